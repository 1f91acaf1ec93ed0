"""TransT's feature-fusion network: ECA and CFA modules and the final CFA decoder.

Chen et al., "Transformer Tracking", CVPR 2021, §3.2 (seed 000 §3.1 and its Figure 8): the
template features (z) and the search-region features (x), flattened to token sequences, pass
through N fusion layers. Each layer has

* two **ego-context augment** (ECA) modules, one per branch: multi-head self-attention with the
  position encoding added to queries and keys, a residual connection and LayerNorm;
* two **cross-feature augment** (CFA) modules, one per branch: multi-head cross-attention whose
  queries come from the branch and keys / values from the other branch, residual and LayerNorm,
  then a two-layer ReLU FFN with residual and LayerNorm.

Both CFAs of a layer read the ECA outputs of the same layer. After the N layers a last CFA
(the "decoder") lets the search tokens attend to the template tokens, followed by a LayerNorm;
its output, one vector per search-feature cell, feeds the prediction heads. Attention is scaled
dot-product attention, softmax(Q K^T / sqrt(d_k)) V (seed 000 §3.1, eq. for Attention).

Attribute names follow the published checkpoint (``encoder.layers.{i}.self_attn1``,
``multihead_attn2``, ``linear11``, ``norm23``, ``decoder.layers.0.multihead_attn``,
``decoder.norm``, ...). Sequences here are batch-first: (B, L, d).
"""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor, nn


class FeatureFusionLayer(nn.Module):
    """One fusion layer: ECA on each branch, then CFA (attention + FFN) on each branch.

    Branch 1 is the template, branch 2 the search region. Post-norm residual blocks.
    """

    def __init__(self, d_model: int, nhead: int, dim_feedforward: int, dropout: float) -> None:
        super().__init__()

        def attn() -> nn.MultiheadAttention:
            return nn.MultiheadAttention(d_model, nhead, dropout=dropout, batch_first=True)

        # ECA (self-attention) of each branch
        self.self_attn1, self.self_attn2 = attn(), attn()
        # CFA cross-attention of each branch
        self.multihead_attn1, self.multihead_attn2 = attn(), attn()
        # CFA feed-forward networks
        self.linear11 = nn.Linear(d_model, dim_feedforward)
        self.linear12 = nn.Linear(dim_feedforward, d_model)
        self.linear21 = nn.Linear(d_model, dim_feedforward)
        self.linear22 = nn.Linear(dim_feedforward, d_model)
        self.norm11, self.norm12, self.norm13 = (nn.LayerNorm(d_model) for _ in range(3))
        self.norm21, self.norm22, self.norm23 = (nn.LayerNorm(d_model) for _ in range(3))
        self.dropout1 = nn.Dropout(dropout)
        self.dropout2 = nn.Dropout(dropout)
        self.dropout11, self.dropout12, self.dropout13 = (nn.Dropout(dropout) for _ in range(3))
        self.dropout21, self.dropout22, self.dropout23 = (nn.Dropout(dropout) for _ in range(3))

    def forward(self, z: Tensor, x: Tensor, pos_z: Tensor, pos_x: Tensor) -> tuple[Tensor, Tensor]:
        """Fuse template tokens ``z`` (B, Lz, d) and search tokens ``x`` (B, Lx, d).

        ``pos_z`` and ``pos_x`` are their position encodings, broadcastable to the same shapes.
        """
        # ECA: self-attention with position-encoded queries and keys
        qz = z + pos_z
        z = self.norm11(z + self.dropout11(self.self_attn1(qz, qz, z, need_weights=False)[0]))
        qx = x + pos_x
        x = self.norm21(x + self.dropout21(self.self_attn2(qx, qx, x, need_weights=False)[0]))
        # CFA: cross-attention, both directions from the ECA outputs
        qz, qx = z + pos_z, x + pos_x
        dz = self.multihead_attn1(qz, qx, x, need_weights=False)[0]
        dx = self.multihead_attn2(qx, qz, z, need_weights=False)[0]
        z = self.norm12(z + self.dropout12(dz))
        z = self.norm13(z + self.dropout13(self.linear12(self.dropout1(F.relu(self.linear11(z))))))
        x = self.norm22(x + self.dropout22(dx))
        x = self.norm23(x + self.dropout23(self.linear22(self.dropout2(F.relu(self.linear21(x))))))
        return z, x


class DecoderCFALayer(nn.Module):
    """The final CFA: search tokens attend to template tokens, then an FFN (post-norm)."""

    def __init__(self, d_model: int, nhead: int, dim_feedforward: int, dropout: float) -> None:
        super().__init__()
        self.multihead_attn = nn.MultiheadAttention(
            d_model, nhead, dropout=dropout, batch_first=True
        )
        self.linear1 = nn.Linear(d_model, dim_feedforward)
        self.linear2 = nn.Linear(dim_feedforward, d_model)
        self.norm1 = nn.LayerNorm(d_model)
        self.norm2 = nn.LayerNorm(d_model)
        self.dropout = nn.Dropout(dropout)
        self.dropout1 = nn.Dropout(dropout)
        self.dropout2 = nn.Dropout(dropout)

    def forward(self, x: Tensor, z: Tensor, pos_x: Tensor, pos_z: Tensor) -> Tensor:
        """Cross-attention of the search features ``x`` (Lx, B, d) to the template features ``z``
        (Lz, B, d), with their position encodings added to queries and keys, then the feed-forward
        block (both residual with layer norm); returns the new ``x`` (Lx, B, d)."""
        a = self.multihead_attn(x + pos_x, z + pos_z, z, need_weights=False)[0]
        x = self.norm1(x + self.dropout1(a))
        return self.norm2(x + self.dropout2(self.linear2(self.dropout(F.relu(self.linear1(x))))))


class Encoder(nn.Module):
    """The stack of N fusion layers (``layers.0`` ... ``layers.{N-1}``)."""

    def __init__(self, n_layers: int, d_model: int, nhead: int, ffn: int, dropout: float) -> None:
        super().__init__()
        self.layers = nn.ModuleList(
            FeatureFusionLayer(d_model, nhead, ffn, dropout) for _ in range(n_layers)
        )

    def forward(self, z: Tensor, x: Tensor, pos_z: Tensor, pos_x: Tensor) -> tuple[Tensor, Tensor]:
        """The template and search features (Lz, B, d) and (Lx, B, d) after every feature-fusion
        layer (self- then cross-attention in both branches), as ``(z, x)``."""
        for layer in self.layers:
            z, x = layer(z, x, pos_z, pos_x)
        return z, x


class Decoder(nn.Module):
    """One decoder CFA layer (``layers.0``) and the closing LayerNorm (``norm``)."""

    def __init__(self, d_model: int, nhead: int, ffn: int, dropout: float) -> None:
        super().__init__()
        self.layers = nn.ModuleList([DecoderCFALayer(d_model, nhead, ffn, dropout)])
        self.norm = nn.LayerNorm(d_model)

    def forward(self, x: Tensor, z: Tensor, pos_x: Tensor, pos_z: Tensor) -> Tensor:
        """The search features ``x`` (Lx, B, d) after the decoder's cross-attention layers to the
        template features ``z``, layer-normalised."""
        for layer in self.layers:
            x = layer(x, z, pos_x, pos_z)
        return self.norm(x)


class FeatureFusionNetwork(nn.Module):
    """Encoder (N fusion layers) + decoder CFA. Xavier-uniform init of all matrices.

    Parameters
    ----------
    d_model : token width d (256 in TransT).
    nhead : attention heads (8 in TransT).
    num_layers : fusion layers N (4 in TransT).
    dim_feedforward : FFN hidden width (2048 in TransT).
    dropout : dropout rate in training (0.1 in TransT).
    """

    def __init__(
        self, d_model: int, nhead: int, num_layers: int, dim_feedforward: int, dropout: float
    ) -> None:
        super().__init__()
        self.d_model = d_model
        self.encoder = Encoder(num_layers, d_model, nhead, dim_feedforward, dropout)
        self.decoder = Decoder(d_model, nhead, dim_feedforward, dropout)
        for p in self.parameters():
            if p.dim() > 1:
                nn.init.xavier_uniform_(p)

    def forward(self, z: Tensor, x: Tensor, pos_z: Tensor, pos_x: Tensor) -> Tensor:
        """Fused search tokens (B, Lx, d) from template tokens ``z`` (B, Lz, d) and search
        tokens ``x`` (B, Lx, d) with position encodings ``pos_z`` (1, Lz, d), ``pos_x``
        (1, Lx, d)."""
        z, x = self.encoder(z, x, pos_z, pos_x)
        return self.decoder(x, z, pos_x, pos_z)
