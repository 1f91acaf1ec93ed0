"""TransT's training loss (Chen et al., "Transformer Tracking", CVPR 2021, §3.3).

Every search-feature cell predicts a target / background label and a box. The cells whose
centres lie inside the ground-truth box are the positives (TransT's matcher takes the feature
vectors "within the ground-truth box"; when a box is so small that no cell centre falls inside,
the cell holding the box centre is the one positive, our choice); all others are background.

* classification: cross-entropy over all cells with the background class down-weighted to
  0.0625 (TransT's ``eos_coef``), class 0 = target, class 1 = background;
* regression, over the positives only: L1 between predicted and true (cx, cy, w, h) (crop
  fractions) and the generalised IoU loss 1 - GIoU, both summed and divided by the number of
  positives in the batch; a target-absent search (``present`` False, a training
  augmentation, our choice) has no positives: all its cells are background;
* total: L = 8.334 L_cls + 5 L_1 + 2 L_GIoU (TransT's weights; seed 000 §3.1 writes the same
  three-term sum with its lambdas).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

#: TransT's loss weights (classification, L1, GIoU) and background weight.
W_CLS, W_L1, W_GIOU = 8.334, 5.0, 2.0
BACKGROUND_WEIGHT = 0.0625


def cxcywh_to_xyxy(b: Tensor) -> Tensor:
    """(..., 4) boxes (cx, cy, w, h) -> (x0, y0, x1, y1)."""
    c, s = b[..., :2], b[..., 2:]
    return torch.cat([c - s / 2, c + s / 2], dim=-1)


def giou(a: Tensor, b: Tensor) -> tuple[Tensor, Tensor]:
    """Element-wise IoU and generalised IoU of (..., 4) boxes in (x0, y0, x1, y1)."""
    area_a = (a[..., 2] - a[..., 0]).clamp(min=0) * (a[..., 3] - a[..., 1]).clamp(min=0)
    area_b = (b[..., 2] - b[..., 0]).clamp(min=0) * (b[..., 3] - b[..., 1]).clamp(min=0)
    lo = torch.maximum(a[..., :2], b[..., :2])
    hi = torch.minimum(a[..., 2:], b[..., 2:])
    inter = (hi - lo).clamp(min=0).prod(dim=-1)
    union = area_a + area_b - inter
    iou = inter / union.clamp(min=1e-9)
    hull = (torch.maximum(a[..., 2:], b[..., 2:]) - torch.minimum(a[..., :2], b[..., :2]))
    hull_area = hull.clamp(min=0).prod(dim=-1)
    return iou, iou - (hull_area - union) / hull_area.clamp(min=1e-9)


def positive_cells(target: Tensor, feature_size: int) -> Tensor:
    """(B, L) bool: cells (row-major over feature_size^2) whose centres lie in the target
    boxes (B, 4) (cx, cy, w, h crop fractions); at least the cell holding the box centre."""
    n = feature_size
    centres = (torch.arange(n, dtype=target.dtype, device=target.device) + 0.5) / n
    x0, y0, x1, y1 = cxcywh_to_xyxy(target).unbind(-1)
    in_x = (centres[None] >= x0[:, None]) & (centres[None] <= x1[:, None])  # (B, n)
    in_y = (centres[None] >= y0[:, None]) & (centres[None] <= y1[:, None])
    mask = (in_y[:, :, None] & in_x[:, None, :]).reshape(len(target), n * n)
    col = (target[:, 0] * n).floor().clamp(0, n - 1).long()
    row = (target[:, 1] * n).floor().clamp(0, n - 1).long()
    mask[torch.arange(len(target)), row * n + col] = True
    return mask


class TransTLoss(nn.Module):
    """L = 8.334 CE + 5 L1 + 2 (1 - GIoU) (TransT's weights), see the module docstring."""

    def __init__(
        self,
        w_cls: float = W_CLS,
        w_l1: float = W_L1,
        w_giou: float = W_GIOU,
        background_weight: float = BACKGROUND_WEIGHT,
    ) -> None:
        super().__init__()
        self.w_cls, self.w_l1, self.w_giou = w_cls, w_l1, w_giou
        self.register_buffer("class_weight", torch.tensor([1.0, background_weight]))

    def forward(
        self, logits: Tensor, boxes: Tensor, target: Tensor, present: Tensor | None = None
    ) -> tuple[Tensor, dict[str, float]]:
        """Total loss and its parts.

        Parameters
        ----------
        logits : (B, L, 2) class logits per cell (class 0 = target).
        boxes : (B, L, 4) predicted (cx, cy, w, h), crop fractions.
        target : (B, 4) true box (cx, cy, w, h), crop fractions.
        present : (B,) bool, False where the search holds no target (every cell is background
            and the pair has no box term); default all True.
        """
        b, n_cells, _ = logits.shape
        fs = int(round(n_cells**0.5))
        pos = positive_cells(target, fs)
        if present is not None:
            pos = pos & present[:, None]
        labels = torch.where(pos, 0, 1)
        l_cls = F.cross_entropy(logits.reshape(-1, 2), labels.reshape(-1), self.class_weight)
        n_pos = pos.sum().clamp(min=1).to(boxes.dtype)
        pred = boxes[pos]
        tgt = target[:, None, :].expand(b, n_cells, 4)[pos]
        l_l1 = F.l1_loss(pred, tgt, reduction="sum") / n_pos
        iou, g = giou(cxcywh_to_xyxy(pred), cxcywh_to_xyxy(tgt))
        l_giou = (1.0 - g).sum() / n_pos
        total = self.w_cls * l_cls + self.w_l1 * l_l1 + self.w_giou * l_giou
        parts = {
            "loss": float(total.detach()),
            "cls": float(l_cls.detach()),
            "l1": float(l_l1.detach()),
            "giou": float(l_giou.detach()),
            "iou": float(iou.detach().mean()) if len(iou) else 0.0,
        }
        return total, parts
