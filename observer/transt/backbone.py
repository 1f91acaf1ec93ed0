"""ResNet backbone of TransT in plain torch (no torchvision), with the sine position encoding.

TransT (Chen et al., "Transformer Tracking", CVPR 2021, §3.1; seed 000 §3.1 uses it as the
backbone tracker) cuts a ResNet-50 after its third stage and removes that stage's stride: the
first bottleneck block of ``layer3`` has stride 1 and dilation 2, so the feature map has an
output stride of 8 (a 256 px search crop gives 32 x 32 features, a 128 px template 16 x 16) with
1024 channels. Only the first block of ``layer3`` is dilated, as in the published code; the
other blocks are plain.

Module names follow the published checkpoint so that its ``'net'`` state dict loads into
``observer.transt.network.TransTNet``: the backbone is a two-element ``nn.Sequential`` whose
element ``0`` holds the ResNet as ``body`` (keys ``backbone.0.body.conv1.weight``,
``backbone.0.body.layer1.0.downsample.1.running_mean``, ...) and whose element ``1`` is the
parameter-free sine position encoding.

Tensors are (batch, channels, height, width); images are ImageNet-normalised RGB.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn


class Bottleneck(nn.Module):
    """ResNet bottleneck block: 1x1 reduce, 3x3 (optionally strided / dilated), 1x1 expand.

    Parameters
    ----------
    inplanes : input channels.
    planes : bottleneck width; the block outputs ``4 * planes`` channels.
    stride : stride of the 3x3 convolution (1 or 2).
    dilation : dilation (and padding) of the 3x3 convolution.
    downsample : projection of the shortcut when the shape changes, else None.
    """

    expansion = 4

    def __init__(
        self,
        inplanes: int,
        planes: int,
        stride: int = 1,
        dilation: int = 1,
        downsample: nn.Module | None = None,
    ) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(inplanes, planes, kernel_size=1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = nn.Conv2d(
            planes,
            planes,
            kernel_size=3,
            stride=stride,
            padding=dilation,
            dilation=dilation,
            bias=False,
        )
        self.bn2 = nn.BatchNorm2d(planes)
        self.conv3 = nn.Conv2d(planes, planes * self.expansion, kernel_size=1, bias=False)
        self.bn3 = nn.BatchNorm2d(planes * self.expansion)
        self.relu = nn.ReLU(inplace=True)
        self.downsample = downsample

    def forward(self, x: Tensor) -> Tensor:
        """The residual block on ``x`` (B, C, H, W): 1x1, 3x3 (strided), 1x1 convolutions with batch
        norm, plus the (downsampled) shortcut, then ReLU; (B, 4·planes, H/stride, W/stride)."""
        shortcut = x if self.downsample is None else self.downsample(x)
        y = self.relu(self.bn1(self.conv1(x)))
        y = self.relu(self.bn2(self.conv2(y)))
        y = self.bn3(self.conv3(y))
        return self.relu(y + shortcut)


class ResNetBody(nn.Module):
    """A ResNet cut after ``layer3``, output stride 8 (stem /4, ``layer2`` /2, ``layer3`` /1).

    Parameters
    ----------
    blocks : number of bottleneck blocks in layer1, layer2, layer3 ((3, 4, 6) is ResNet-50).
    inplanes : stem width (64 for ResNet-50); the stages have bottleneck widths
        ``inplanes * (1, 2, 4)`` and output ``4 *`` that many channels.
    layer3_dilation : dilation of the first block of layer3 (2 in TransT).
    """

    def __init__(
        self, blocks: tuple[int, int, int], inplanes: int = 64, layer3_dilation: int = 2
    ) -> None:
        super().__init__()
        self._inplanes = inplanes
        self.conv1 = nn.Conv2d(3, inplanes, kernel_size=7, stride=2, padding=3, bias=False)
        self.bn1 = nn.BatchNorm2d(inplanes)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(kernel_size=3, stride=2, padding=1)
        self.layer1 = self._stage(inplanes, blocks[0], stride=1, dilation=1)
        self.layer2 = self._stage(inplanes * 2, blocks[1], stride=2, dilation=1)
        self.layer3 = self._stage(inplanes * 4, blocks[2], stride=1, dilation=layer3_dilation)
        self.num_channels = inplanes * 4 * Bottleneck.expansion
        self.stride = 8
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)

    def _stage(self, planes: int, n_blocks: int, stride: int, dilation: int) -> nn.Sequential:
        out = planes * Bottleneck.expansion
        down = None
        if stride != 1 or self._inplanes != out:
            down = nn.Sequential(
                nn.Conv2d(self._inplanes, out, kernel_size=1, stride=stride, bias=False),
                nn.BatchNorm2d(out),
            )
        layers = [Bottleneck(self._inplanes, planes, stride, dilation, down)]
        self._inplanes = out
        layers += [Bottleneck(out, planes) for _ in range(1, n_blocks)]
        return nn.Sequential(*layers)

    def forward(self, x: Tensor) -> Tensor:
        """Features of images ``x`` (B, 3, H, W), ImageNet-normalised: the stem and layers 1-3,
        (B, num_channels, H/8, W/8) (layer 3 dilated instead of strided, as TransT's backbone)."""
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        return self.layer3(self.layer2(self.layer1(x)))


class _Body(nn.Module):
    """Holds the ResNet as ``body`` (the published key prefix ``backbone.0.body``)."""

    def __init__(self, body: ResNetBody) -> None:
        super().__init__()
        self.body = body
        self.num_channels = body.num_channels

    def forward(self, x: Tensor) -> Tensor:
        return self.body(x)


class SinePositionEncoding(nn.Module):
    """Normalised 2-D sine position encoding (DETR / TransT "sine"), no parameters.

    For a feature map of H x W cells, cell (i, j) (row, column, from 0) has normalised
    coordinates ``y = 2π (i + 1) / H`` and ``x = 2π (j + 1) / W`` (TransT's encoding of an
    unpadded map). Each is expanded into ``num_pos_feats`` channels
    ``sin(c / T^(2k/F)), cos(c / T^(2k/F))`` (interleaved, k = 0 .. F/2 - 1, T = 10000,
    F = num_pos_feats); the y channels come first. Output (1, 2 F, H, W), so ``2 F`` must equal
    the transformer width d.
    """

    def __init__(self, num_pos_feats: int, temperature: float = 10000.0) -> None:
        super().__init__()
        if num_pos_feats % 2:
            raise ValueError(f"num_pos_feats must be even, got {num_pos_feats}")
        self.num_pos_feats = num_pos_feats
        self.temperature = temperature
        self._cache: dict[tuple[int, int], Tensor] = {}

    def encode(self, height: int, width: int) -> Tensor:
        """The encoding (1, 2 F, height, width), float32, cached per size."""
        key = (int(height), int(width))
        if key not in self._cache:
            f = self.num_pos_feats
            k = torch.arange(f, dtype=torch.float64)
            inv = self.temperature ** (2.0 * torch.div(k, 2, rounding_mode="floor") / f)
            ys = (torch.arange(height, dtype=torch.float64) + 1.0) / height * 2.0 * math.pi
            xs = (torch.arange(width, dtype=torch.float64) + 1.0) / width * 2.0 * math.pi

            def expand(c: Tensor) -> Tensor:
                a = c[:, None] / inv  # (n, F)
                out = torch.empty_like(a)
                out[:, 0::2] = a[:, 0::2].sin()
                out[:, 1::2] = a[:, 1::2].cos()
                return out

            py = expand(ys)[:, None, :].expand(height, width, f)
            px = expand(xs)[None, :, :].expand(height, width, f)
            pos = torch.cat([py, px], dim=-1).permute(2, 0, 1)[None]
            self._cache[key] = pos.to(torch.float32).contiguous()
        return self._cache[key]

    def forward(self, feature: Tensor) -> Tensor:
        """The position encoding (1, 2·num_pos_feats, H, W) of a feature map ``feature``
        (B, C, H, W), on its device."""
        return self.encode(feature.shape[-2], feature.shape[-1]).to(feature.device)


class Backbone(nn.Sequential):
    """ResNet features and their position encoding: element 0 the ResNet (as ``body``),
    element 1 the sine encoding (the published layout, so the keys read
    ``backbone.0.body.*``). ``forward(x)`` returns (features (B, C, H/8, W/8), pos (1, d, ...)).
    """

    def __init__(self, body: ResNetBody, d_model: int) -> None:
        super().__init__(_Body(body), SinePositionEncoding(d_model // 2))
        self.num_channels = body.num_channels

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:  # type: ignore[override]
        """The ResNet features of ``x`` (B, 3, H, W) and their position encoding, as a pair."""
        feat = self[0](x)
        return feat, self[1](feat)
