"""The TransT network (Chen et al., "Transformer Tracking", CVPR 2021), two configurations.

Seed 000 §3.1 (Figure 8) builds GK-TransT on this network. One code path, two sizes:

* ``TRANST50``: the published layout. ResNet-50 to ``layer3`` (blocks 3, 4, 6; the first block
  of layer3 with stride 1 and dilation 2, output stride 8, 1024 channels), 1x1 input projection
  to d = 256, sine position encoding, 4 fusion layers with 8 heads and FFN width 2048, decoder
  CFA, 3-layer MLP heads. Template crop 128 px at context factor 2, search crop 256 px at context
  factor 4 (16 x 16 and 32 x 32 feature cells). Module names match the published checkpoint, so
  its ``'net'`` state dict loads with ``load_official_state_dict``.
* ``SMALL``: the same architecture sized for real time on two CPU cores (our choice, about
  1.6 M parameters): bottleneck ResNet with stem width 16 and blocks (2, 2, 2) (256 channels,
  still output stride 8 with the dilated layer3), d = 128, 4 heads, FFN 512, 2 fusion layers,
  template 64 px and search 128 px (8 x 8 and 16 x 16 cells), same context factors. It is trained
  here on analytic renders (``observer.transt.training.train``) and shipped in ``weights/``.

Outputs, per search-feature cell (row-major over the H x W map): ``logits`` (B, H W, 2) with
class 0 = target and class 1 = background (TransT's convention), and ``boxes`` (B, H W, 4) =
sigmoid of the box head, (cx, cy, w, h) as fractions of the search crop's side.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field, model_validator
from torch import Tensor, nn

from observer.transt.backbone import Backbone, ResNetBody
from observer.transt.fusion import FeatureFusionNetwork


class TransTConfig(BaseModel):
    """Architecture and crop geometry of a TransT network (one code path for both sizes)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(description="Configuration name ('transt50', 'small', ...).")
    backbone_blocks: tuple[int, int, int] = Field(
        description="Bottleneck blocks in layer1..layer3 ((3, 4, 6) = ResNet-50)."
    )
    backbone_inplanes: int = Field(64, ge=4, description="ResNet stem width (64 = ResNet-50).")
    layer3_dilation: int = Field(2, ge=1, description="TransT: layer3 stride 1, dilation 2.")
    d_model: int = Field(256, ge=8, description="Transformer width d.")
    nhead: int = Field(8, ge=1, description="Attention heads.")
    dim_feedforward: int = Field(2048, ge=8, description="FFN hidden width.")
    num_fusion_layers: int = Field(4, ge=1, description="Feature-fusion layers N.")
    dropout: float = Field(0.1, ge=0.0, lt=1.0, description="Dropout in training.")
    template_size: int = Field(128, ge=16, description="Template crop side, px.")
    search_size: int = Field(256, ge=16, description="Search crop side, px.")
    template_factor: float = Field(2.0, gt=1.0, description="Template context factor.")
    search_factor: float = Field(4.0, gt=1.0, description="Search context factor.")
    window_influence: float = Field(
        0.49, ge=0.0, le=1.0, description="Hanning-window weight in the score (TransT: 0.49)."
    )

    @model_validator(mode="after")
    def _check(self) -> TransTConfig:
        if self.d_model % self.nhead or self.d_model % 4:
            raise ValueError(
                f"d_model ({self.d_model}) must be divisible by nhead ({self.nhead}) and by 4"
            )
        for name in ("template_size", "search_size"):
            if getattr(self, name) % 8:
                raise ValueError(f"{name} must be a multiple of the output stride 8")
        return self

    @property
    def stride(self) -> int:
        """Output stride of the backbone (8 for both configurations)."""
        return 8

    @property
    def template_feature_size(self) -> int:
        """Template feature map side, cells."""
        return self.template_size // self.stride

    @property
    def search_feature_size(self) -> int:
        """Search feature map side, cells."""
        return self.search_size // self.stride


#: The published TransT (Chen et al. 2021, §4.1 and the released settings).
TRANST50 = TransTConfig(
    name="transt50",
    backbone_blocks=(3, 4, 6),
    backbone_inplanes=64,
    d_model=256,
    nhead=8,
    dim_feedforward=2048,
    num_fusion_layers=4,
    template_size=128,
    search_size=256,
)

#: Our real-time configuration (our choice; sized for about 10 ms a frame on two CPU cores).
SMALL = TransTConfig(
    name="small",
    backbone_blocks=(2, 2, 2),
    backbone_inplanes=16,
    d_model=128,
    nhead=4,
    dim_feedforward=512,
    num_fusion_layers=2,
    template_size=64,
    search_size=128,
)

CONFIGS: dict[str, TransTConfig] = {c.name: c for c in (TRANST50, SMALL)}


class MLP(nn.Module):
    """Multi-layer perceptron with ReLU between layers (TransT's prediction heads)."""

    def __init__(self, in_dim: int, hidden_dim: int, out_dim: int, num_layers: int) -> None:
        super().__init__()
        dims = [in_dim] + [hidden_dim] * (num_layers - 1) + [out_dim]
        pairs = zip(dims[:-1], dims[1:], strict=True)
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in pairs)

    def forward(self, x: Tensor) -> Tensor:
        """``x`` (..., in_dim) through the linear layers with ReLU between them, (..., out_dim)."""
        for i, layer in enumerate(self.layers):
            x = layer(x)
            if i < len(self.layers) - 1:
                x = F.relu(x)
        return x


class TransTNet(nn.Module):
    """TransT: backbone, 1x1 input projection, feature fusion, classification and box heads.

    ``forward(template, search)`` takes ImageNet-normalised RGB crops (B, 3, Sz, Sz) and
    (B, 3, Sx, Sx) and returns ``(logits, boxes)`` (see the module docstring). For tracking,
    ``template_features`` runs the backbone on the template once and ``track_features`` runs
    the rest per frame, as the published tracker does.
    """

    def __init__(self, config: TransTConfig) -> None:
        super().__init__()
        self.config = config
        c = config
        body = ResNetBody(c.backbone_blocks, c.backbone_inplanes, c.layer3_dilation)
        self.backbone = Backbone(body, c.d_model)
        self.input_proj = nn.Conv2d(body.num_channels, c.d_model, kernel_size=1)
        self.featurefusion_network = FeatureFusionNetwork(
            c.d_model, c.nhead, c.num_fusion_layers, c.dim_feedforward, c.dropout
        )
        self.class_embed = MLP(c.d_model, c.d_model, 2, 3)
        self.bbox_embed = MLP(c.d_model, c.d_model, 4, 3)

    def _tokens(self, image: Tensor) -> tuple[Tensor, Tensor]:
        """Projected tokens (B, L, d) and position encoding (1, L, d) of one crop batch."""
        feat, pos = self.backbone(image)
        tok = self.input_proj(feat).flatten(2).transpose(1, 2)
        return tok, pos.flatten(2).transpose(1, 2)

    def template_features(self, template: Tensor) -> tuple[Tensor, Tensor]:
        """Template tokens and their position encoding, computed once per target."""
        return self._tokens(template)

    def search_position(self, height: int, width: int) -> Tensor:
        """Position encoding (1, height·width, d) of a search feature map of ``height`` x
        ``width`` cells: the trained map's own (``search_feature_size`` cells a side) when it
        is that size; a smaller map centred in it takes the centre of the trained map's
        encoding, so that each cell keeps the encoding it had at the trained size and the
        heads' outputs stay fractions of the trained-size crop (``TransTTracker``'s smaller
        search crop). Other sizes get the encoding of their own size (as in training)."""
        n = self.config.search_feature_size
        enc = self.backbone[1].encode
        if (height, width) != (n, n) and height <= n and width <= n \
                and (n - height) % 2 == 0 and (n - width) % 2 == 0:
            r, c = (n - height) // 2, (n - width) // 2
            pos = enc(n, n)[:, :, r:r + height, c:c + width]
        else:
            pos = enc(height, width)
        return pos.flatten(2).transpose(1, 2)

    def track_features(self, search: Tensor, z: Tensor, pos_z: Tensor) -> tuple[Tensor, Tensor]:
        """Logits (B, L, 2) and boxes (B, L, 4) for search crops against cached template
        tokens ``z`` (B or 1, Lz, d) with encoding ``pos_z``; a search crop smaller than the
        trained one is encoded as the centre of a trained-size crop (``search_position``)."""
        feat, _ = self.backbone(search)
        x = self.input_proj(feat).flatten(2).transpose(1, 2)
        pos_x = self.search_position(int(feat.shape[-2]), int(feat.shape[-1])).to(x.device)
        if z.shape[0] != x.shape[0]:
            z = z.expand(x.shape[0], -1, -1)
        hs = self.featurefusion_network(z, x, pos_z, pos_x)
        return self.class_embed(hs), self.bbox_embed(hs).sigmoid()

    def forward(self, template: Tensor, search: Tensor) -> tuple[Tensor, Tensor]:
        """Class logits (B, H·W, 2) and boxes (B, H·W, 4) as (cx, cy, w, h) fractions of the search
        crop, one per search-feature cell, for template crops ``template`` and search crops
        ``search`` (B, 3, side, side), ImageNet-normalised."""
        z, pos_z = self.template_features(template)
        return self.track_features(search, z, pos_z)


def build_transt(config: TransTConfig | str) -> TransTNet:
    """A freshly initialised ``TransTNet`` for a configuration or its name."""
    if isinstance(config, str):
        if config not in CONFIGS:
            raise ValueError(f"unknown TransT configuration {config!r}; one of {list(CONFIGS)}")
        config = CONFIGS[config]
    return TransTNet(config)


def count_parameters(net: nn.Module) -> int:
    """Number of parameters (trainable or not; buffers excluded)."""
    return sum(p.numel() for p in net.parameters())


# --- loading the published checkpoint ----------------------------------------------------------

#: Keys that BatchNorm adds to a state dict but that carry no weights; their absence or presence
#: is not a mismatch worth failing for.
_BENIGN_SUFFIXES = ("num_batches_tracked",)


@dataclass
class LoadReport:
    """What happened when a state dict was loaded into a network.

    Attributes
    ----------
    missing : keys the network has that the state dict lacks.
    unexpected : keys of the state dict that the network does not have.
    shape_mismatch : (key, network shape, state-dict shape) of keys present in both.
    loaded : keys copied into the network.
    ignored : benign keys skipped on either side (BatchNorm ``num_batches_tracked``).
    """

    missing: list[str] = field(default_factory=list)
    unexpected: list[str] = field(default_factory=list)
    shape_mismatch: list[tuple[str, tuple[int, ...], tuple[int, ...]]] = field(
        default_factory=list
    )
    loaded: list[str] = field(default_factory=list)
    ignored: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when every weight of the network was loaded and nothing was left over."""
        return not (self.missing or self.unexpected or self.shape_mismatch)

    def summary(self, max_keys: int = 12) -> str:
        """Human-readable report listing up to ``max_keys`` keys of each kind."""

        def block(title: str, items: list) -> list[str]:
            if not items:
                return []
            lines = [f"{title} ({len(items)}):"]
            lines += [f"  {it}" for it in items[:max_keys]]
            if len(items) > max_keys:
                lines.append(f"  ... and {len(items) - max_keys} more")
            return lines

        lines = [f"loaded {len(self.loaded)} tensors"]
        lines += block("missing keys (in the network, not in the checkpoint)", self.missing)
        lines += block("unexpected keys (in the checkpoint, not in the network)", self.unexpected)
        lines += block(
            "shape mismatches (key, network shape, checkpoint shape)", self.shape_mismatch
        )
        return "\n".join(lines)


def _extract_state_dict(checkpoint: object) -> dict[str, Tensor]:
    """The state dict inside a published-TransT checkpoint (its ``'net'`` entry), a bare state
    dict, or a path to either; a leading ``module.`` (DataParallel) is stripped."""
    if isinstance(checkpoint, (str, Path)):
        path = Path(checkpoint)
        if not path.is_file():
            raise FileNotFoundError(f"TransT checkpoint not found: {path}")
        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    if not isinstance(checkpoint, Mapping):
        raise TypeError(f"expected a checkpoint dict or state dict, got {type(checkpoint)}")
    sd = checkpoint["net"] if "net" in checkpoint else checkpoint
    if not isinstance(sd, Mapping):
        raise TypeError("the checkpoint's 'net' entry is not a state dict")
    out = {}
    for k, v in sd.items():
        if not isinstance(v, Tensor):
            raise TypeError(f"state-dict entry {k!r} is a {type(v).__name__}, not a tensor")
        out[k.removeprefix("module.")] = v
    return out


def load_official_state_dict(
    net: TransTNet, checkpoint: object, strict: bool = True
) -> LoadReport:
    """Load published-TransT weights (key layout of the released ``transt.pth``) into ``net``.

    Parameters
    ----------
    net : a ``TransTNet`` (normally ``build_transt("transt50")``).
    checkpoint : the checkpoint dict (its ``'net'`` entry is used), a bare state dict, or a
        path to a ``.pth`` file holding either.
    strict : raise ``ValueError`` with the report when any key is missing, unexpected or of the
        wrong shape (nothing is loaded then). With ``strict=False`` the matching tensors are
        loaded and the report says what was not.

    Returns
    -------
    LoadReport
        Missing, unexpected and mis-shaped keys; BatchNorm ``num_batches_tracked`` counters are
        ignored on both sides.
    """
    sd = _extract_state_dict(checkpoint)
    own = net.state_dict()
    report = LoadReport()
    for k in own:
        if k.endswith(_BENIGN_SUFFIXES) and k not in sd:
            report.ignored.append(k)
        elif k not in sd:
            report.missing.append(k)
    for k, v in sd.items():
        if k not in own:
            (report.ignored if k.endswith(_BENIGN_SUFFIXES) else report.unexpected).append(k)
        elif tuple(own[k].shape) != tuple(v.shape):
            report.shape_mismatch.append((k, tuple(own[k].shape), tuple(v.shape)))
    if strict and not report.ok:
        raise ValueError(
            "the checkpoint does not match this TransT configuration "
            f"({net.config.name}):\n" + report.summary()
        )
    bad = {m[0] for m in report.shape_mismatch}
    to_load = {k: v for k, v in sd.items() if k in own and k not in bad}
    with torch.no_grad():
        for k, v in to_load.items():
            own[k].copy_(v.to(own[k].dtype))
    report.loaded = sorted(to_load)
    return report
