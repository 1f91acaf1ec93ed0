"""TransT (Chen et al., CVPR 2021; seed 000 §3.1): network layout, checkpoint loading, weights,
crops, loss, and tracking with the shipped ``small`` weights against rendered ground truth.

Independent references: parameter counts from closed-form layer formulas, the published
checkpoint's key names written out by hand from its naming scheme, TransT's decoding rule
applied by hand to a stubbed network output, brute-force loops for the loss's positive cells,
and the renderer's ground truth (``Frame.marker_px``, full-sensor px) for tracking.
"""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest
import torch

from observer.transt import (
    SMALL,
    SMALL_WEIGHTS,
    TRANST50,
    TransTTracker,
    WeightsError,
    build_transt,
    count_parameters,
    load_official_state_dict,
)
from observer.transt.backbone import SinePositionEncoding
from observer.transt.crop import box_to_crop, context_side, crop_square, crop_to_box, normalise
from observer.transt.tracker import hanning_window
from observer.transt.training.losses import TransTLoss, giou, positive_cells
from observer.transt.training.validation import (
    marker_box_image,
    red_box_image,
    validation_sequence,
)
from observer.transt.weights import REBUILD_COMMAND, load_weights, save_weights, verify

torch.set_num_threads(2)

#: Validation sequences for the shipped model: seeds never used for training (training pairs
#: come from seed streams [1, i]; the model card's sequences are 1001-1003).
TEST_SEQUENCE_SEEDS = (2001, 2002)
#: Bounds on the shipped small model's centre error on them (full-sensor px; the marker is
#: about 190 sensor px across and the seed's precision threshold is 20 px, seed 000 §4.2).
#: Measured here: median 3.2 / 3.9 px, max 7.3 / 8.7 px (red / yellow); the bounds leave room.
MEDIAN_ERR_BOUND_PX = 8.0
MAX_ERR_BOUND_PX = 25.0


# --- independent parameter counts ---------------------------------------------------------------
def _bn(c: int) -> int:
    return 2 * c


def _resnet_params(blocks: tuple[int, int, int], w: int) -> int:
    """Closed-form parameter count of a bottleneck ResNet cut after layer3."""
    n = 3 * w * 49 + _bn(w)
    cin = w
    for planes, nb in zip((w, 2 * w, 4 * w), blocks, strict=True):
        out = 4 * planes
        for i in range(nb):
            n += cin * planes + _bn(planes) + 9 * planes * planes + _bn(planes)
            n += planes * out + _bn(out)
            if i == 0:  # every stage's first block projects its shortcut (1x1 conv + BN)
                n += cin * out + _bn(out)
            cin = out
    return n


def _transt_params(c) -> int:
    d, f, n_layers = c.d_model, c.dim_feedforward, c.num_fusion_layers
    mha = 4 * d * d + 4 * d
    ffn = d * f + f + f * d + d
    ln = 2 * d
    layer = 4 * mha + 2 * ffn + 6 * ln
    decoder = mha + ffn + 2 * ln + ln
    cin = 16 * c.backbone_inplanes
    proj = cin * d + d
    heads = 2 * (2 * (d * d + d)) + (2 * d + 4 * d + 6)
    return (
        _resnet_params(c.backbone_blocks, c.backbone_inplanes)
        + proj
        + n_layers * layer
        + decoder
        + heads
    )


@pytest.mark.parametrize("config", [SMALL, TRANST50], ids=["small", "transt50"])
def test_parameter_count_matches_closed_form(config) -> None:
    net = build_transt(config)
    assert count_parameters(net) == _transt_params(config)


def test_parameter_counts_in_range() -> None:
    assert 1_000_000 <= count_parameters(build_transt("small")) <= 2_000_000
    # the published TransT-ResNet50 has about 23 M parameters
    assert 22_500_000 <= count_parameters(build_transt("transt50")) <= 23_500_000


@pytest.mark.parametrize("config", [SMALL, TRANST50], ids=["small", "transt50"])
def test_output_shapes(config) -> None:
    torch.manual_seed(0)
    net = build_transt(config).eval()
    z = torch.randn(1, 3, config.template_size, config.template_size)
    x = torch.randn(1, 3, config.search_size, config.search_size)
    with torch.no_grad():
        zt, pos_z = net.template_features(z)
        logits, boxes = net.track_features(x, zt, pos_z)
        logits2, boxes2 = net(z, x)
    n = (config.search_size // 8) ** 2
    assert zt.shape == (1, (config.template_size // 8) ** 2, config.d_model)
    assert logits.shape == (1, n, 2) and boxes.shape == (1, n, 4)
    assert torch.all((boxes > 0) & (boxes < 1))
    assert torch.allclose(logits, logits2, atol=1e-5) and torch.allclose(boxes, boxes2, atol=1e-6)


def test_transt50_layout_is_the_published_one() -> None:
    c = TRANST50
    assert (c.backbone_blocks, c.backbone_inplanes, c.d_model, c.nhead) == ((3, 4, 6), 64, 256, 8)
    assert (c.dim_feedforward, c.num_fusion_layers, c.template_size, c.search_size) == (
        2048, 4, 128, 256)
    assert (c.template_factor, c.search_factor, c.window_influence) == (2.0, 4.0, 0.49)
    body = build_transt(c).backbone[0].body
    conv = body.layer3[0].conv2
    assert conv.stride == (1, 1) and conv.dilation == (2, 2)
    assert body.layer3[1].conv2.dilation == (1, 1)
    assert body.layer2[0].conv2.stride == (2, 2)
    feat = body(torch.zeros(1, 3, 64, 64))
    assert feat.shape == (1, 1024, 8, 8)  # output stride 8


# --- the published checkpoint's key layout ------------------------------------------------------
def _official_keys(c) -> set[str]:
    """Keys of the published TransT checkpoint's 'net' state dict, from its naming scheme."""
    keys = set()
    bn = ("weight", "bias", "running_mean", "running_var", "num_batches_tracked")
    p = "backbone.0.body."
    keys.add(p + "conv1.weight")
    keys |= {p + "bn1." + s for s in bn}
    for li, nb in enumerate(c.backbone_blocks, start=1):
        for b in range(nb):
            q = f"{p}layer{li}.{b}."
            keys |= {q + f"conv{i}.weight" for i in (1, 2, 3)}
            keys |= {q + f"bn{i}.{s}" for i in (1, 2, 3) for s in bn}
            if b == 0:
                keys.add(q + "downsample.0.weight")
                keys |= {q + "downsample.1." + s for s in bn}
    keys |= {"input_proj.weight", "input_proj.bias"}
    mha = ("in_proj_weight", "in_proj_bias", "out_proj.weight", "out_proj.bias")
    for i in range(c.num_fusion_layers):
        q = f"featurefusion_network.encoder.layers.{i}."
        for a in ("self_attn1", "self_attn2", "multihead_attn1", "multihead_attn2"):
            keys |= {q + a + "." + s for s in mha}
        for lin in ("linear11", "linear12", "linear21", "linear22"):
            keys |= {q + lin + ".weight", q + lin + ".bias"}
        for nm in ("norm11", "norm12", "norm13", "norm21", "norm22", "norm23"):
            keys |= {q + nm + ".weight", q + nm + ".bias"}
    q = "featurefusion_network.decoder."
    keys |= {q + "layers.0.multihead_attn." + s for s in mha}
    for nm in ("layers.0.linear1", "layers.0.linear2", "layers.0.norm1", "layers.0.norm2", "norm"):
        keys |= {q + nm + ".weight", q + nm + ".bias"}
    for head in ("class_embed", "bbox_embed"):
        keys |= {f"{head}.layers.{i}.{s}" for i in range(3) for s in ("weight", "bias")}
    return keys


@pytest.fixture(scope="module")
def transt50() -> torch.nn.Module:
    torch.manual_seed(0)
    return build_transt("transt50")


@pytest.fixture(scope="module")
def official_sd(transt50) -> dict[str, torch.Tensor]:
    """A state dict in the official key layout with values different from ``transt50``'s."""
    g = torch.Generator().manual_seed(1)
    return {
        k: (torch.randn(v.shape, generator=g) if v.is_floating_point() else v.clone())
        for k, v in transt50.state_dict().items()
    }


def test_module_names_match_official_keys(transt50) -> None:
    assert set(transt50.state_dict()) == _official_keys(TRANST50)


def test_official_checkpoint_loads(transt50, official_sd, tmp_path) -> None:
    path = tmp_path / "transt.pth"
    torch.save({"epoch": 1000, "net_type": "transt_resnet50", "net": official_sd}, path)
    rep = load_official_state_dict(transt50, path)
    assert rep.ok and not rep.missing and not rep.unexpected
    sd = transt50.state_dict()
    for k in ("backbone.0.body.layer3.5.conv3.weight", "class_embed.layers.2.bias",
              "featurefusion_network.decoder.norm.weight"):
        assert torch.equal(sd[k], official_sd[k])


def test_official_loader_reports_mismatches(transt50, official_sd) -> None:
    bad = dict(official_sd)
    del bad["featurefusion_network.encoder.layers.3.linear22.bias"]
    bad["extra_head.weight"] = torch.zeros(3)
    bad["input_proj.weight"] = torch.zeros(128, 1024, 1, 1)
    bad = {"module." + k: v for k, v in bad.items()}  # a DataParallel prefix is stripped
    with pytest.raises(ValueError) as err:
        load_official_state_dict(transt50, {"net": bad})
    msg = str(err.value)
    assert "featurefusion_network.encoder.layers.3.linear22.bias" in msg
    assert "extra_head.weight" in msg and "input_proj.weight" in msg
    rep = load_official_state_dict(transt50, {"net": bad}, strict=False)
    assert rep.missing == ["featurefusion_network.encoder.layers.3.linear22.bias"]
    assert rep.unexpected == ["extra_head.weight"]
    assert [m[0] for m in rep.shape_mismatch] == ["input_proj.weight"]
    assert not rep.ok and "missing keys" in rep.summary()
    # BatchNorm step counters are not weights: their absence is not a mismatch
    no_counters = {k: v for k, v in official_sd.items() if "num_batches_tracked" not in k}
    assert load_official_state_dict(transt50, no_counters).ok


def test_small_config_loads_with_the_same_loader() -> None:
    a, b = build_transt("small"), build_transt("small")
    rep = load_official_state_dict(b, {"net": a.state_dict()})
    assert rep.ok and all(torch.equal(a.state_dict()[k], b.state_dict()[k]) for k in rep.loaded)
    with pytest.raises(ValueError, match="shape mismatches"):
        load_official_state_dict(build_transt("small"), {"net": build_transt("transt50")
                                                         .state_dict()})


# --- weights file and SHA-256 --------------------------------------------------------------------
def test_shipped_weights_verify_and_load() -> None:
    digest = verify(SMALL_WEIGHTS)
    assert len(digest) == 64
    assert SMALL_WEIGHTS.stat().st_size < 20 * 2**20
    net, meta = load_weights()
    assert net.config == SMALL and meta["steps"] > 0


def test_corrupt_or_missing_weights_are_refused(tmp_path) -> None:
    copy = tmp_path / "transt_small.pt"
    shutil.copy(SMALL_WEIGHTS, copy)
    shutil.copy(SMALL_WEIGHTS.with_name(SMALL_WEIGHTS.name + ".sha256"),
                tmp_path / "transt_small.pt.sha256")
    load_weights(copy)  # an intact copy loads
    data = bytearray(copy.read_bytes())
    data[len(data) // 2] ^= 0xFF
    copy.write_bytes(bytes(data))
    for call in (lambda: load_weights(copy), lambda: TransTTracker.small(copy)):
        with pytest.raises(WeightsError) as err:
            call()
        assert str(copy) in str(err.value) and REBUILD_COMMAND in str(err.value)
    with pytest.raises(WeightsError, match="not found") as err:
        load_weights(tmp_path / "nothing.pt")
    assert REBUILD_COMMAND in str(err.value)
    checksum = tmp_path / "transt_small.pt.sha256"
    for text, words in (("", "is empty"), ("  \n", "is empty"),
                        ("abc123  transt_small.pt\n", "64-digit hex"),
                        ("z" * 64 + "  transt_small.pt\n", "64-digit hex")):
        checksum.write_text(text)  # an empty .sha256 raised IndexError before
        with pytest.raises(WeightsError, match=words) as err:
            load_weights(copy)
        assert str(checksum) in str(err.value) and REBUILD_COMMAND in str(err.value)
    checksum.write_bytes(b"\xff\xfe")
    with pytest.raises(WeightsError, match="cannot be read as text"):
        load_weights(copy)
    checksum.unlink()
    with pytest.raises(WeightsError, match="checksum file not found"):
        load_weights(copy)


def _card_copy(tmp_path, digest: str, config: str = "small", parameters: int | None = None,
               name: str = "transt_small.pt") -> None:
    """A model card in ``tmp_path`` that names ``name`` with ``digest``, ``config`` and
    ``parameters`` (default the shipped card's count)."""
    from observer.transt.weights import card_facts

    facts = card_facts(SMALL_WEIGHTS.parent / "MODEL_CARD.md")
    n = facts.parameters if parameters is None else parameters
    (tmp_path / "MODEL_CARD.md").write_text(
        f"# card\n\n- Architecture: configuration `{config}`: ...\n- Parameters: {n:,}.\n"
        f"- File: `{name}`, SHA-256 `{digest}` (checked at every load).\n")


def test_shipped_model_card_names_the_shipped_file_and_its_digest() -> None:
    from observer.transt.weights import card_facts

    facts = card_facts(SMALL_WEIGHTS.parent / "MODEL_CARD.md")
    net, _ = load_weights()
    assert facts.file == SMALL_WEIGHTS.name and facts.config == "small"
    assert facts.sha256 == verify(SMALL_WEIGHTS)
    assert facts.parameters == count_parameters(net)


def test_weights_that_do_not_match_their_model_card_are_refused(tmp_path) -> None:
    """A card beside the weights that names them: another SHA-256, another configuration,
    an architecture other than the code's, or another parameter count is refused naming the
    rebuild command; a card naming another file is not about these weights."""
    copy = tmp_path / "transt_small.pt"
    shutil.copy(SMALL_WEIGHTS, copy)
    shutil.copy(SMALL_WEIGHTS.with_name(SMALL_WEIGHTS.name + ".sha256"),
                tmp_path / "transt_small.pt.sha256")
    digest = verify(copy)
    _card_copy(tmp_path, digest)
    load_weights(copy)  # card and file agree
    cases = [(dict(digest="0" * 64), "does not match its model card"),
             (dict(digest=digest, config="transt50"), "holds a `small` network"),
             (dict(digest=digest, parameters=123), "has 1,")]
    for kwargs, words in cases:
        _card_copy(tmp_path, **kwargs)
        with pytest.raises(WeightsError, match=words) as err:
            load_weights(copy)
        assert REBUILD_COMMAND in str(err.value)
    _card_copy(tmp_path, "0" * 64, name="other.pt")
    load_weights(copy)
    # a `small` network whose architecture is not the code's `small`
    torch.manual_seed(0)
    odd = build_transt(SMALL.model_copy(update={"dim_feedforward": 256}))
    d = save_weights(odd, tmp_path / "transt_small.pt")
    _card_copy(tmp_path, d)
    with pytest.raises(WeightsError, match="architecture other than the code's") as err:
        load_weights(tmp_path / "transt_small.pt")
    assert "dim_feedforward: 256 vs 512" in str(err.value) and REBUILD_COMMAND in str(err.value)


def test_save_and_load_roundtrip(tmp_path) -> None:
    torch.manual_seed(3)
    net = build_transt("small")
    digest = save_weights(net, tmp_path / "w.pt", {"steps": 1})
    back, meta = load_weights(tmp_path / "w.pt", expected_sha256=digest)
    assert meta == {"steps": 1}
    assert all(torch.equal(v, back.state_dict()[k]) for k, v in net.state_dict().items())


# --- crops, position encoding, window, loss -------------------------------------------------------
def test_context_side_is_transt_formula() -> None:
    w, h = 30.0, 50.0
    p = (4 - 1) * (w + h) / 2
    assert context_side((w, h), 4.0) == pytest.approx(math.sqrt((w + p) * (h + p)))
    assert context_side((20.0, 20.0), 2.0) == pytest.approx(40.0)


def test_normalise_is_imagenet_normalisation() -> None:
    """ImageNet normalisation ((v/255 - mean)/std per channel, channels first) written out
    here: the lookup gives the float32 elementwise formula's bits and the float64 values to
    float32 rounding, for a batch and for a single crop."""
    rng = np.random.default_rng(5)
    crops = rng.integers(0, 256, (2, 16, 24, 3)).astype(np.uint8)
    mean, std = (0.485, 0.456, 0.406), (0.229, 0.224, 0.225)
    out = normalise(crops)
    assert out.shape == (2, 3, 16, 24) and out.dtype == np.float32 and out.flags.c_contiguous
    f32 = crops.astype(np.float32) * np.float32(1.0 / 255.0)
    f32 = (f32 - np.float32(mean)) / np.float32(std)
    assert np.array_equal(out, np.moveaxis(f32, -1, 1))
    f64 = np.stack([(crops[..., c] / 255.0 - mean[c]) / std[c] for c in range(3)], axis=1)
    np.testing.assert_allclose(out, f64, rtol=0.0, atol=1e-6)
    assert np.array_equal(normalise(crops[1]), out[1])


def test_crop_geometry_against_a_drawn_square() -> None:
    img = np.zeros((200, 300, 3), np.uint8)
    img[90:110, 140:160] = 255  # covers [139.5, 159.5] x [89.5, 109.5], centre (149.5, 99.5)
    centre, side = np.array([143.25, 104.5]), 80.0
    crop = crop_square(img, centre, side, 64, pad_rgb=(0, 0, 0)).astype(float)[..., 0]
    v, u = np.mgrid[0:64, 0:64]
    cu, cv = (crop * u).sum() / crop.sum(), (crop * v).sum() / crop.sum()
    # crop pixel (j, i) centre <-> crop fraction ((j + 0.5)/64, (i + 0.5)/64)
    frac = np.array([(cu + 0.5) / 64, (cv + 0.5) / 64])
    expect = box_to_crop([139.5, 89.5, 20.0, 20.0], centre, side)
    assert np.allclose(frac, expect[:2], atol=0.01 / 64 * 10)
    assert np.allclose(expect[2:], 20.0 / side)
    back = crop_to_box(expect, centre, side)
    assert np.allclose(back, [139.5, 89.5, 20.0, 20.0])
    # outside the frame: the pad colour
    assert np.all(crop_square(img, (5.0, 5.0), 100.0, 32, pad_rgb=(7, 8, 9))[0, 0] == [7, 8, 9])


def test_sine_position_encoding_formula() -> None:
    pe = SinePositionEncoding(8).encode(4, 5)
    assert pe.shape == (1, 16, 4, 5)
    i, j = 2, 3
    y, x = (i + 1) / 4 * 2 * math.pi, (j + 1) / 5 * 2 * math.pi
    for k in range(8):
        t = 10000 ** (2 * (k // 2) / 8)
        f = math.sin if k % 2 == 0 else math.cos
        assert pe[0, k, i, j].item() == pytest.approx(f(y / t), abs=1e-6)
        assert pe[0, 8 + k, i, j].item() == pytest.approx(f(x / t), abs=1e-6)


def test_hanning_window() -> None:
    w = hanning_window(16).reshape(16, 16)
    n = np.arange(16)
    h = 0.5 - 0.5 * np.cos(2 * np.pi * n / 15)
    assert np.allclose(w, np.outer(h, h), atol=1e-7)


def test_positive_cells_brute_force() -> None:
    rng = np.random.default_rng(0)
    boxes = np.column_stack([rng.uniform(0.2, 0.8, (50, 2)), rng.uniform(0.01, 0.4, (50, 2))])
    mask = positive_cells(torch.tensor(boxes, dtype=torch.float32), 16).numpy()
    for b, m in zip(boxes, mask, strict=True):
        cx, cy, w, h = b
        expect = np.zeros((16, 16), bool)
        for r in range(16):
            for c in range(16):
                x, y = (c + 0.5) / 16, (r + 0.5) / 16
                expect[r, c] = abs(x - cx) <= w / 2 + 1e-7 and abs(y - cy) <= h / 2 + 1e-7
        expect[int(cy * 16), int(cx * 16)] = True
        assert np.array_equal(m.reshape(16, 16), expect)


def test_loss_against_hand_computation() -> None:
    torch.manual_seed(0)
    logits = torch.randn(2, 64, 2)
    target = torch.tensor([[0.5, 0.5, 0.3, 0.2], [0.3, 0.6, 0.1, 0.15]])
    boxes = torch.rand(2, 64, 4) * 0.5 + 0.25
    total, parts = TransTLoss()(logits, boxes, target)
    pos = positive_cells(target, 8)
    lab = (~pos).long()
    logp = torch.log_softmax(logits, -1)
    w = torch.where(lab == 0, 1.0, 0.0625)
    nll = -(logp.gather(-1, lab[..., None])[..., 0] * w).sum() / w.sum()
    n_pos = pos.sum()
    tgt = target[:, None].expand(2, 64, 4)
    l1 = (boxes - tgt).abs().sum(-1)[pos].sum() / n_pos

    def xyxy(b):
        return torch.cat([b[..., :2] - b[..., 2:] / 2, b[..., :2] + b[..., 2:] / 2], -1)

    _, g = giou(xyxy(boxes[pos]), xyxy(tgt[pos]))
    lg = (1 - g).sum() / n_pos
    assert parts["cls"] == pytest.approx(float(nll), rel=1e-5)
    assert parts["l1"] == pytest.approx(float(l1), rel=1e-5)
    assert float(total) == pytest.approx(float(8.334 * nll + 5 * l1 + 2 * lg), rel=1e-5)
    # a perfect box regression costs nothing but the classification term
    _, p2 = TransTLoss()(logits, tgt.clone(), target)
    assert p2["l1"] == pytest.approx(0.0, abs=1e-6) and p2["giou"] == pytest.approx(0, abs=1e-6)


def test_loss_of_a_target_absent_search_is_background_only() -> None:
    """A search without its target: every cell labelled background (hand-computed weighted
    cross-entropy), no box term, and no gradient into its boxes."""
    torch.manual_seed(1)
    logits = torch.randn(2, 64, 2)
    target = torch.tensor([[0.5, 0.5, 0.3, 0.2], [0.3, 0.6, 0.1, 0.15]])
    boxes = (torch.rand(2, 64, 4) * 0.5 + 0.25).requires_grad_(True)
    present = torch.tensor([True, False])
    total, parts = TransTLoss()(logits, boxes, target, present)
    pos = positive_cells(target, 8) & present[:, None]
    lab = (~pos).long()
    logp = torch.log_softmax(logits, -1)
    w = torch.where(lab == 0, 1.0, 0.0625)
    nll = -(logp.gather(-1, lab[..., None])[..., 0] * w).sum() / w.sum()
    assert parts["cls"] == pytest.approx(float(nll), rel=1e-5)
    assert not pos[1].any()
    total.backward()
    assert float(boxes.grad[1].abs().max()) == 0.0 and float(boxes.grad[0].abs().max()) > 0.0


@pytest.mark.parametrize("seed", range(12))
def test_hide_target_removes_the_marker(seed: int) -> None:
    """On a drawn search crop (textured grey rotor, a red disc inside the label box), the
    removal leaves no pixel of the disc's colour and keeps the crop away from the box."""
    from observer.transt.training.augment import hide_target

    rng = np.random.default_rng(100 + seed)
    side = 64
    crop = (rng.uniform(90, 140, (side, side, 1)) * np.ones(3)).astype(np.uint8)
    centre = rng.uniform(20, 44, 2)
    r = rng.uniform(4, 7)
    yy, xx = np.mgrid[0:side, 0:side]
    disc = np.hypot(xx + 0.5 - centre[0], yy + 0.5 - centre[1]) <= r
    crop[disc] = (220, 20, 25)
    box = np.array([*centre, 2 * r, 2 * r], np.float32) / side
    before = crop.copy()
    hide_target(crop, box, np.random.default_rng(seed))
    red = (crop[..., 0] > 180) & (crop[..., 1] < 60) & (crop[..., 2] < 60)
    assert not red.any()
    # the removed region is the box grown at most 2.2 times: outside it nothing changes
    outside = (np.abs(xx + 0.5 - centre[0]) > 2.3 * r) | (np.abs(yy + 0.5 - centre[1]) > 2.3 * r)
    assert np.array_equal(crop[outside], before[outside])


def test_giou_known_values() -> None:
    a = torch.tensor([[0.0, 0.0, 2.0, 2.0]])
    b = torch.tensor([[1.0, 1.0, 3.0, 3.0]])
    iou, g = giou(a, b)
    assert iou.item() == pytest.approx(1 / 7)
    assert g.item() == pytest.approx(1 / 7 - (9 - 7) / 9)


# --- tracker decoding with a stubbed network -----------------------------------------------------
class _StubRunner:
    """Network stand-in: a probability peak at one cell and a known box everywhere."""

    def __init__(self, n: int, peak: int, box: np.ndarray) -> None:
        self.n, self.peak, self.box = n, peak, box
        self.seen = []

    def set_template(self, template) -> None:
        pass

    def __call__(self, search):
        self.seen.append(search)
        logits = np.zeros((self.n * self.n, 2), np.float32)
        logits[self.peak, 0] = 4.0
        boxes = np.tile(self.box.astype(np.float32), (self.n * self.n, 1))
        return logits, boxes


def test_tracker_decodes_as_transt() -> None:
    frame = (np.random.default_rng(0).integers(0, 255, (240, 320, 3))).astype(np.uint8)
    trk = TransTTracker.from_config("small")
    box0 = np.array([100.0, 80.0, 30.0, 20.0])
    trk.initialize(frame, box0)
    n = SMALL.search_feature_size
    pred = np.array([0.6, 0.45, 0.25, 0.18])
    trk._runner = _StubRunner(n, peak=n * 7 + 8, box=pred)
    res = trk.track(frame)
    box, score = res.box_image_px, res.score
    side = context_side(box0[2:], 4.0)
    c0 = box0[:2] + box0[2:] / 2
    cx, cy = c0 - side / 2 + pred[:2] * side
    w, h = pred[2:] * side
    assert np.allclose(box, [cx - w / 2, cy - h / 2, w, h])
    assert score == pytest.approx(math.exp(4) / (1 + math.exp(4)), rel=1e-6)
    assert trk.last.ok and trk.last.search_side_px == pytest.approx(side)
    # an external search centre moves the crop, not the decoding rule
    trk2 = TransTTracker.from_config("small")
    trk2.initialize(frame, box0)
    trk2._runner = _StubRunner(n, peak=0, box=pred)
    ext = np.array([150.0, 120.0])
    res = trk2.track(frame, search_centre_image_px=ext)
    box2, _ = res.box_image_px, res.score
    assert np.allclose(trk2.last.search_centre_image_px, ext)
    assert np.allclose(box2[:2] + box2[2:] / 2, ext - side / 2 + pred[:2] * side)
    assert trk2.compute_time_s > 0


def test_window_prefers_the_centre_on_a_tie() -> None:
    frame = (np.random.default_rng(1).integers(0, 255, (240, 320, 3))).astype(np.uint8)
    trk = TransTTracker.from_config("small")
    trk.initialize(frame, [100.0, 80.0, 30.0, 30.0])
    n = SMALL.search_feature_size

    class Flat(_StubRunner):
        def __call__(self, search):
            logits = np.zeros((n * n, 2), np.float32)
            boxes = np.zeros((n * n, 4), np.float32)
            r, c = np.divmod(np.arange(n * n), n)
            boxes[:, 0], boxes[:, 1] = (c + 0.5) / n, (r + 0.5) / n
            boxes[:, 2:] = 0.2
            return logits, boxes

    trk._runner = Flat(n, 0, np.zeros(4))
    res = trk.track(frame)
    box, score = res.box_image_px, res.score
    side = context_side((30.0, 30.0), 4.0)
    centre = box[:2] + box[2:] / 2
    # equal probabilities everywhere: the window picks a central cell (7 or 8 of 0..15)
    assert np.all(np.abs(centre - [115.0, 95.0]) <= side / n)
    assert score == pytest.approx(0.5)


def test_a_frame_scored_at_or_below_the_hold_leaves_the_state_as_it_was() -> None:
    """A network that puts a far box on a weak peak (target probability 1/(1 + e^1.5) = 0.18,
    every other cell 0.0025):
    TransT's own rule (no hold) moves the state to that box; with ``hold_below_score`` 0.2 the
    tracker reports its previous box and keeps its state, at 0.18 and exactly at the
    threshold; a confident peak (0.98) still moves it. Bad thresholds are refused."""
    frame = (np.random.default_rng(2).integers(0, 255, (240, 320, 3))).astype(np.uint8)
    n = SMALL.search_feature_size
    far = np.array([0.9, 0.1, 0.6, 0.6])  # top-right of the crop, 3x the box
    box0 = np.array([100.0, 80.0, 30.0, 30.0])

    class Weak(_StubRunner):
        def __init__(self, logit: float) -> None:
            super().__init__(n, n * (n // 2) + n // 2, far)  # the window favours it
            self.logit = logit

        def __call__(self, search):
            logits, boxes = super().__call__(search)
            logits[:, 0] = -6.0  # every other cell: background
            logits[self.peak, 0] = self.logit
            return logits, boxes

    def step(hold, logit):
        trk = TransTTracker.from_config("small")
        trk.hold_below_score = hold
        trk.initialize(frame, box0)
        trk._runner = Weak(logit)
        res = trk.track(frame)
        return res, trk

    res, trk = step(None, -1.5)
    assert res.score == pytest.approx(1.0 / (1.0 + math.exp(1.5)), rel=1e-6)
    assert not np.allclose(res.box_image_px, box0, atol=1.0)
    assert not np.allclose(trk.size_image_px, box0[2:], atol=1.0)
    for hold in (0.2, res.score):  # below, and exactly at, the threshold
        res, trk = step(hold, -1.5)
        np.testing.assert_allclose(res.box_image_px, box0, atol=1e-9)
        np.testing.assert_allclose(trk.centre_image_px, box0[:2] + box0[2:] / 2, atol=1e-9)
        np.testing.assert_allclose(trk.size_image_px, box0[2:], atol=1e-9)
        assert res.valid and res.measured and res.score < 0.2 + 1e-12
    res, trk = step(0.2, 4.0)
    assert res.score > 0.9 and not np.allclose(res.box_image_px, box0, atol=1.0)
    for bad in (-0.1, 1.0, 2.0):
        with pytest.raises(ValueError, match="hold_below_score"):
            TransTTracker(build_transt("small"), hold_below_score=bad)


# --- bad input ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def clean_frame():
    return validation_sequence(2001, 1)[0]


def test_init_rejects_bad_input(clean_frame) -> None:
    trk = TransTTracker.from_config("small")
    img, box = clean_frame.image, red_box_image(clean_frame)
    bad_inits = [
        (np.zeros((0, 0, 3), np.uint8), box, "empty"),
        (img.astype(np.float32), box, "dtype"),
        (img[..., 0], box, "shape"),
        ([[1, 2, 3]], box, "numpy"),
        (img, [np.nan, 1, 2, 3], "finite"),
        (img, [10, 10, 0, 5], "w, h > 0"),
        (img, [900, 900, 20, 20], "outside"),
        (np.zeros_like(img), box, "uniform"),
    ]
    for frame, b, match in bad_inits:
        with pytest.raises(ValueError, match=match):
            trk.initialize(frame, b)
    assert not trk.initialised


def test_track_survives_bad_input(clean_frame) -> None:
    trk = TransTTracker.from_config("small")
    res = trk.track(clean_frame.image)  # before init
    box, score = res.box_image_px, res.score
    assert np.all(np.isnan(box)) and score == 0.0 and "init" in trk.last.status
    trk.initialize(clean_frame.image, red_box_image(clean_frame))
    state = trk.centre_image_px.copy()
    nan_frame = clean_frame.image.astype(np.float64)
    nan_frame[10, 10] = np.nan
    bad = [
        np.zeros_like(clean_frame.image),  # all black
        nan_frame,  # NaN (and a float dtype)
        np.zeros((0, 0, 3), np.uint8),  # empty
        clean_frame.image[..., :2],  # wrong shape
        None,
        np.full_like(clean_frame.image, 255),  # all white
    ]
    for frame in bad:
        res = trk.track(frame)
        box, score = res.box_image_px, res.score
        assert np.all(np.isnan(box)) and score == 0.0 and not trk.last.ok
        assert np.allclose(trk.centre_image_px, state)
    # A valid RGB frame of another size than the init frame (it scored 0.99 before): its
    # pixels are not the coordinates the track is kept in.
    img = clean_frame.image
    for other in (np.ascontiguousarray(img[::2, ::2]), np.pad(img, ((0, 8), (0, 8), (0, 0)))):
        res = trk.track(other)
        assert np.all(np.isnan(res.box_image_px)) and res.score == 0.0 and not res.valid
        assert not trk.last.ok
        assert "differs from the init frame" in trk.last.status, trk.last.status
        assert "differs from the init frame" in res.reason, res.reason
        assert np.allclose(trk.centre_image_px, state)
    res = trk.track(clean_frame.image, search_centre_image_px=[np.nan, 3.0])
    box, score = res.box_image_px, res.score
    assert np.all(np.isnan(box)) and "search_centre" in trk.last.status
    res = trk.track(clean_frame.image, search_centre_image_px=[-5000.0, -5000.0])
    box, score = res.box_image_px, res.score
    assert np.all(np.isnan(box)) and "outside" in trk.last.status
    res = trk.track(clean_frame.image)  # the track goes on
    box, score = res.box_image_px, res.score
    assert trk.last.ok and np.all(np.isfinite(box))


# --- the shipped model on rendered validation frames ----------------------------------------------
@pytest.mark.parametrize("marker", [0, 1], ids=["red", "yellow"])
def test_shipped_small_tracks_the_markers(marker: int) -> None:
    """The red main marker (GK-TransT's target) and, from its own template, the yellow one
    (the dual-TransT baseline's second tracker)."""
    trk = TransTTracker.small()
    errs, scores = [], []
    for seed in TEST_SEQUENCE_SEEDS:
        frames = validation_sequence(seed, 30)
        trk.initialize(frames[0].image, marker_box_image(frames[0], marker))
        for f in frames[1:]:
            res = trk.track(f.image)
            box, score = res.box_image_px, res.score
            c_sensor = (box[:2] + box[2:] / 2 + 0.5) * f.binning - 0.5
            errs.append(np.hypot(*(c_sensor - f.marker_px[marker])))
            scores.append(score)
    errs = np.asarray(errs)
    assert np.median(errs) < MEDIAN_ERR_BOUND_PX, np.median(errs)
    assert errs.max() < MAX_ERR_BOUND_PX, errs.max()
    assert np.median(scores) > 0.5


def test_shipped_small_scores_occlusion_low() -> None:
    frames = validation_sequence(2002, 3)
    trk = TransTTracker.small()
    trk.initialize(frames[0].image, red_box_image(frames[0]))
    res = trk.track(frames[1].image)
    _, s_visible = res.box_image_px, res.score
    img = frames[2].image.copy()
    x, y, w, h = red_box_image(frames[2])
    img[int(y - 10):int(y + h + 10), int(x - 10):int(x + w + 10)] = 0  # black box + margin
    res = trk.track(img)
    _, s_hidden = res.box_image_px, res.score
    assert s_hidden < 0.5 < s_visible


def test_onnx_backend_matches_eager(clean_frame) -> None:
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    net, _ = load_weights()
    out = []
    for backend in ("eager", "onnx"):
        trk = TransTTracker(net, backend=backend)
        trk.initialize(clean_frame.image, red_box_image(clean_frame))
        res = trk.track(clean_frame.image)
        out.append((res.box_image_px, res.score))
    assert np.allclose(out[0][0], out[1][0], atol=1e-2)
    assert out[0][1] == pytest.approx(out[1][1], abs=1e-4)


def test_a_smaller_search_crop_is_the_centre_of_the_trained_one(clean_frame) -> None:
    """``search_size`` 96 of the trained 128: the search region is its centre 3/4 at the same
    image scale, the network sees the centre 12 x 12 cells of the trained 16 x 16 position
    encoding and window, and the boxes keep the trained region's scale (the box head's
    fractions are of the trained-size crop). ONNX Runtime runs it like eager PyTorch."""
    net, _ = load_weights()
    n, m = SMALL.search_feature_size, 96 // SMALL.stride
    full = SinePositionEncoding(SMALL.d_model // 2).encode(n, n)[0]  # (d, 16, 16)
    want = full[:, 2:14, 2:14].reshape(SMALL.d_model, m * m).T
    assert torch.equal(net.search_position(m, m)[0], want)
    assert torch.equal(net.search_position(n, n)[0], full.reshape(SMALL.d_model, n * n).T)
    out = []
    for backend in ("eager", "onnx"):
        trk = TransTTracker(net, backend=backend, search_size=96)
        box = np.asarray(red_box_image(clean_frame), dtype=float)
        trk.initialize(clean_frame.image, box)
        res = trk.track(clean_frame.image)
        assert trk.last.search_side_px == pytest.approx(
            0.75 * context_side(box[2:], SMALL.search_factor))
        out.append((res.box_image_px, res.score))
        np.testing.assert_allclose(trk._windows[96].reshape(m, m),
                                   np.outer(np.hanning(n), np.hanning(n))[2:14, 2:14], atol=1e-7)
    assert np.allclose(out[0][0], out[1][0], atol=1e-2)
    assert out[0][1] == pytest.approx(out[1][1], abs=1e-4)
    # the same marker, found at the trained scale: the box size within 20 % of the truth's
    assert np.all(np.abs(out[0][0][2:] / box[2:] - 1.0) < 0.2)
    assert np.hypot(*(out[0][0][:2] + out[0][0][2:] / 2 - box[:2] - box[2:] / 2)) < 6.0
    for bad in (104, 136, 8, 96.0, 0):
        with pytest.raises(ValueError, match="search_size"):
            TransTTracker(net, search_size=bad)
    # per frame: a usable size searches that crop, a bad one fails the frame, keeping the track
    trk = TransTTracker(net)
    trk.initialize(clean_frame.image, box)
    res = trk.track(clean_frame.image, search_size=96)
    assert res.valid and trk.last.search_side_px == pytest.approx(
        0.75 * context_side(trk.size_image_px, SMALL.search_factor), rel=0.2)
    before = trk.centre_image_px.copy()
    res = trk.track(clean_frame.image, search_size=100)
    assert not res.valid and "search_size" in res.reason
    assert np.array_equal(trk.centre_image_px, before)


def test_small_default_backend_and_fallback(monkeypatch) -> None:
    import observer.transt.tracker as tracker_mod

    expected = "onnx"
    try:
        import onnx  # noqa: F401
        import onnxruntime  # noqa: F401
    except ImportError:
        expected = "eager"
    assert TransTTracker.small().backend == expected
    monkeypatch.setattr(tracker_mod, "DEFAULT_BACKEND", "unavailable")
    assert TransTTracker.small().backend == "eager"


def test_a_crop_size_onnx_cannot_build_falls_back_to_eager_with_one_warning(
        monkeypatch, clean_frame) -> None:
    """When ONNX Runtime cannot build the session of a smaller search crop, ``small()`` runs
    eager PyTorch and says so once; the tracker then tracks like eager PyTorch (same box to
    float32 rounding), not silently otherwise."""
    pytest.importorskip("onnxruntime")
    from observer.transt.service import NetworkService

    def refuse(self, search_size):
        if self.backend == "onnx" and search_size != self.net.config.search_size:
            raise RuntimeError("no session for this size")

    monkeypatch.setattr(NetworkService, "prepare", refuse)
    with pytest.warns(UserWarning, match="running eager PyTorch") as caught:
        trk = TransTTracker.small(search_size=96)
    assert len(caught) == 1 and trk.backend == "eager"
    box = red_box_image(clean_frame)
    trk.initialize(clean_frame.image, box)
    got = trk.track(clean_frame.image)
    ref = TransTTracker(load_weights()[0], backend="eager", search_size=96)
    ref.initialize(clean_frame.image, box)
    want = ref.track(clean_frame.image)
    assert got.valid and np.allclose(got.box_image_px, want.box_image_px, atol=1e-4)
