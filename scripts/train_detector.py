#!/usr/bin/env python3
"""Train the learned crack detector (a small U-Net) and export it as ONNX (a development tool).

Usage (the ``train`` extra: ``pip install -e '.[train]'``)::

    nice -n 19 python scripts/train_detector.py train --data DIR --out services/detector/models \
        [--epochs N] [--minutes M] [--seed S] [--widths C C C C] [--norm batch] [--pos-weight W]
        [--dice-weight W] [--crop PX] [--crops-per-image K] [--walls SEED ...] [--init MODEL.onnx]
        [--scale LO HI] [--wide-cracks P]
    python scripts/train_detector.py evaluate --data DIR --model services/detector/models/crack_unet.onnx --out DIR
    python scripts/train_detector.py probe --data DIR [--model MODEL.onnx] [--out FILE.json]

``DIR`` holds ``crackforest/`` and ``deepcrack-train/`` (each ``images/`` and ``masks/``). The splits are
fixed by name before any training (:func:`services.detector.learned.splits`): CrackForest's even-numbered
half (the odd sorted indices) and every fifth DeepCrack-train image are held out for testing and never seen
by training or model selection; of the rest, every eighth image is the validation set (choice of epoch and
threshold), the others are trained on. ``--walls`` adds the mission's kind of surface to the training set:
the planned captures of the monorail scenario's synthetic wall made with other texture seeds than the
mission's own (which is refused), with their exact crack masks. ``--init`` starts from an exported model
(fine-tuning: its weights, the folded threshold taken out) instead of a random initialisation.

Why JAX: its CPU wheels are ~100 MB (PyTorch's registry wheels pull ~3 GB of CUDA libraries), XLA compiles
the whole training step for the CPU, and the network is a dozen convolutions, so no layer library is
needed: the parameters are a dict of arrays that :func:`export_onnx` writes as an ONNX graph with the
``onnx`` package's helper API (OpenCV's ``cv2.dnn`` runs it at inference, :mod:`services.detector.learned`).

Network (U-Net, Ronneberger et al. 2015, narrowed): widths 8-16-32-64 over four scales, two 3x3
convolutions per encoder scale, one per decoder scale after nearest upsampling and concatenation with the
skip, a 1x1 head (``--widths`` changes the widths). The input is standardised per image (zero mean, unit
variance), which also makes the model indifferent to exposure; ``--norm batch`` adds batch normalisation
after every convolution but the head (Ioffe & Szegedy 2015), folded into the convolutions on export, so
the ONNX graph is the same either way. Loss: binary cross-entropy (crack pixels weighted ``--pos-weight``)
plus ``--dice-weight`` times the soft Dice loss (the Dice term targets the F-measure directly under the
~3 % crack share). The decision threshold chosen on
validation is folded into the head's bias, so the exported model's probability 0.5 is the cut.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import re
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from services.detector.learned import STRIDE, splits  # noqa: E402  (the shipped model's contract: split, padding)

log = logging.getLogger("train_detector")

WIDTHS = (8, 16, 32, 64)
SCALE = (0.75, 1.33)  # the random scale of a training image (augment)
WIDE = (4, 14)  # the width range of a painted wide crack, px (paint_wide_crack)
DATASETS = ("crackforest", "deepcrack-train")
THRESHOLDS = np.round(np.arange(0.10, 0.91, 0.05), 2)


# ---------------------------------------------------------------- data
def load_pairs(root: Path, dataset: str, part: str, limit: int | None = None) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, grey uint8, mask bool) of one split of ``root/dataset``."""
    d = root / dataset
    names = [p.stem for p in sorted((d / "images").iterdir()) if p.suffix.lower() in (".jpg", ".png")]
    if not names:
        raise SystemExit(f"train_detector: no images in {d / 'images'}")
    out = []
    for n in splits(names, dataset)[part][:limit]:
        img = next(p for p in (d / "images").iterdir() if p.stem == n)
        g = cv2.imread(str(img), cv2.IMREAD_GRAYSCALE)
        m = cv2.imread(str(d / "masks" / f"{n}.png"), cv2.IMREAD_GRAYSCALE)
        if g is None or m is None or g.shape != m.shape:
            raise SystemExit(f"train_detector: cannot read {img} or its mask")
        out.append((n, g, m > 127))
    return out


def wall_pairs(seeds: list[int], scenario: str = "monorail") -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, grey, truth) of every planned 640 x 480 capture of ``scenario``'s synthetic wall made with each
    texture seed (:func:`edge.world.wall.synthetic_surface`): the mission's kind of surface, whose texture
    (stains, grain lines) is unlike the photographs' and is not a crack. Never the mission's own seed."""
    from edge.world.wall import SURFACE_SEED, synthetic_surface
    from protocol.scenario import load_scenario
    from services.inspection.captures import decode, synthetic_captures

    if SURFACE_SEED in seeds:
        raise SystemExit(f"train_detector: wall seed {SURFACE_SEED} is the mission's own wall; choose others")
    sc = load_scenario(scenario)
    out = []
    for seed in seeds:
        for k, c in enumerate(synthetic_captures(sc, synthetic_surface(sc, seed=seed))):
            out.append((f"wall{seed}-{k:02d}", decode(c), c.truth > 127))
    return out


def onnx_params(path: Path) -> tuple[dict[str, dict[str, np.ndarray]], tuple[int, ...]]:
    """The parameters (HWIO kernels, biases) and widths of a model this script exported, the head's folded
    threshold taken out again (a warm start: ``train --init``)."""
    import onnx
    from onnx import numpy_helper

    m = onnx.load(str(path))
    t = re.search(r"threshold ([0-9.]+)", m.doc_string or "")
    if t is None:
        raise SystemExit(f"train_detector: {path} is not a model this script exported (no threshold in its doc string)")
    arrs = {i.name: numpy_helper.to_array(i) for i in m.graph.initializer}
    params = {}
    for name in (k.removesuffix(".w") for k in arrs if k.endswith(".w")):
        w, b = arrs[f"{name}.w"], arrs[f"{name}.b"].astype(np.float32)
        if name == "head":
            th = float(t.group(1))
            b = b + np.float32(math.log(th / (1 - th)))
        params[name] = {"w": np.ascontiguousarray(w.transpose(2, 3, 1, 0)).astype(np.float32), "b": b}
    return params, tuple(int(params[f"e{k}a"]["w"].shape[3]) for k in range(1, scales_of(params) + 1))


def standardise(g: np.ndarray) -> np.ndarray:
    """Per-image zero mean, unit variance (float32); the runtime does the same."""
    x = g.astype(np.float32)
    return (x - x.mean()) / (x.std() + 1.0)


def augment(rng: np.random.Generator, g: np.ndarray, m: np.ndarray, crop: int,
            scale: tuple[float, float] = SCALE) -> tuple[np.ndarray, np.ndarray]:
    """One training crop: random scale (log-uniform over ``scale``), gamma (0.7-1.4), crop (70 % centred near
    a crack pixel), flips and 90-degree turns, Gaussian blur or noise; standardised over the scaled image."""
    s = math.exp(rng.uniform(math.log(scale[0]), math.log(scale[1])))
    if abs(s - 1) > 0.03:
        h, w = g.shape
        size = (max(crop, round(w * s)), max(crop, round(h * s)))
        g = cv2.resize(g, size, interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
        m = cv2.resize(m.astype(np.uint8) * 255, size, interpolation=cv2.INTER_LINEAR) > 127
    gamma = math.exp(rng.uniform(math.log(0.7), math.log(1.4)))
    g = (255.0 * (g.astype(np.float32) / 255.0) ** gamma).astype(np.float32)
    x = standardise(g)
    h, w = x.shape
    ys, xs = np.nonzero(m)
    if len(ys) and rng.random() < 0.7:
        k = rng.integers(len(ys))
        cy = int(np.clip(ys[k] + rng.integers(-crop // 3, crop // 3 + 1), crop // 2, h - crop + crop // 2))
        cx = int(np.clip(xs[k] + rng.integers(-crop // 3, crop // 3 + 1), crop // 2, w - crop + crop // 2))
        y0, x0 = cy - crop // 2, cx - crop // 2
    else:
        y0, x0 = int(rng.integers(0, h - crop + 1)), int(rng.integers(0, w - crop + 1))
    x, mm = x[y0:y0 + crop, x0:x0 + crop], m[y0:y0 + crop, x0:x0 + crop]
    k = int(rng.integers(4))
    x, mm = np.rot90(x, k), np.rot90(mm, k)
    if rng.random() < 0.5:
        x, mm = x[:, ::-1], mm[:, ::-1]
    r = rng.random()
    if r < 0.2:
        x = cv2.GaussianBlur(np.ascontiguousarray(x), (3, 3), rng.uniform(0.3, 0.9))
    elif r < 0.4:
        x = x + rng.normal(0, rng.uniform(0.05, 0.2), x.shape).astype(np.float32)
    return np.ascontiguousarray(x, np.float32), np.ascontiguousarray(mm, np.float32)


def paint_wide_crack(rng: np.random.Generator, x: np.ndarray, m: np.ndarray,
                     width: tuple[int, int] = WIDE) -> tuple[np.ndarray, np.ndarray]:
    """A crop with one more crack painted on it, wider than most of the photographs' (``width`` px, the mission's
    captures show cracks 4.5-10 px wide, docs/detector.md): a polyline of 4-11 short legs turning up to 35 degrees,
    its width drifting by a pixel per leg, 1-3 standard deviations darker than the crop with the crop's own
    texture kept at half strength inside and a blurred edge; its pixels join the mask. ``x`` standardised."""
    h, w = x.shape
    layer = np.zeros((h, w), np.uint8)
    pt = np.array([rng.uniform(0.2, 0.8) * w, rng.uniform(0.2, 0.8) * h])
    heading = rng.uniform(0, 2 * math.pi)
    thick = int(rng.integers(width[0], width[1] + 1))
    for _ in range(int(rng.integers(4, 12))):
        heading += rng.uniform(-0.6, 0.6)
        nxt = pt + rng.uniform(0.08, 0.25) * max(h, w) * np.array([math.cos(heading), math.sin(heading)])
        cv2.line(layer, (round(pt[0]), round(pt[1])), (round(nxt[0]), round(nxt[1])), 1, thick)
        thick = int(np.clip(thick + rng.integers(-1, 2), width[0], width[1]))
        pt = nxt
    a = cv2.GaussianBlur(layer.astype(np.float32), (0, 0), rng.uniform(0.5, 1.2))
    dark = float(x.mean()) - rng.uniform(1.0, 3.0)
    inside = dark + 0.5 * (x - float(x.mean()))
    return (x * (1 - a) + inside * a).astype(np.float32), np.maximum(m, layer.astype(np.float32))


# ---------------------------------------------------------------- model (JAX)
def layer_shapes(widths: tuple[int, ...] = WIDTHS) -> dict[str, tuple[int, int, int, int]]:
    """Name -> HWIO kernel shape of every convolution: encoder scale ``k`` (1-based) ``e<k>a``/``e<k>b``, decoder
    ``d<k>`` for every scale but the deepest, the 1x1 ``head``; one scale per width."""
    c = (1, *widths)
    out: dict[str, tuple[int, int, int, int]] = {}
    for k in range(1, len(widths) + 1):
        out[f"e{k}a"], out[f"e{k}b"] = (3, 3, c[k - 1], c[k]), (3, 3, c[k], c[k])
    for k in range(len(widths) - 1, 0, -1):
        out[f"d{k}"] = (3, 3, c[k + 1] + c[k], c[k])
    out["head"] = (1, 1, c[1], 1)
    return out


def init_params(seed: int, widths: tuple[int, ...] = WIDTHS, norm: bool = False) -> dict[str, dict[str, np.ndarray]]:
    """He-normal kernels, zero biases (the head's bias at the crack prior, logit(0.03)); with ``norm`` every
    convolution but the head also gets a batch-norm scale ``g`` (ones) and shift ``beta`` (zeros)."""
    rng = np.random.default_rng(seed)
    out = {}
    for name, shp in layer_shapes(widths).items():
        fan_in = shp[0] * shp[1] * shp[2]
        w = rng.normal(0, math.sqrt(2.0 / fan_in), shp).astype(np.float32)
        b = np.zeros(shp[3], np.float32)
        if name == "head":
            w *= 0.1
            b[:] = math.log(0.03 / 0.97)
        out[name] = {"w": w, "b": b}
        if norm and name != "head":
            out[name].update(g=np.ones(shp[3], np.float32), beta=np.zeros(shp[3], np.float32))
    return out


#: batch norm's variance floor (Ioffe & Szegedy 2015, eq. in Alg. 1) and running-average momentum
BN_EPS = 1e-5
BN_MOMENTUM = 0.9
#: training batches whose statistics the averaged weights' batch norm is recomputed on (``--ema``)
BN_BATCHES = 16


def scales_of(params) -> int:  # noqa: ANN001
    """The number of encoder scales of ``params``."""
    return sum(1 for k in params if re.fullmatch(r"e[0-9]+a", k))


def init_stats(params) -> dict[str, dict[str, np.ndarray]]:  # noqa: ANN001
    """Running batch-norm statistics (mean 0, variance 1) of every normalised layer of ``params``."""
    return {k: {"mean": np.zeros_like(v["g"]), "var": np.ones_like(v["g"])} for k, v in params.items() if "g" in v}


def forward(params, x, stats=None, batch_stats=None):  # noqa: ANN001, ANN201 - JAX pytrees
    """Logits (N, H, W, 1) of NHWC input; H and W multiples of 2 ** (scales - 1).

    Layers with batch norm (``g``/``beta`` in ``params``) use the running ``stats`` when given (inference),
    else the batch's own statistics (training), which are stored into the dict ``batch_stats`` if given."""
    import jax
    import jax.numpy as jnp
    from jax import lax

    def conv(name, h):  # noqa: ANN001, ANN202
        p = params[name]
        h = lax.conv_general_dilated(h, p["w"], (1, 1), "SAME",
                                     dimension_numbers=("NHWC", "HWIO", "NHWC")) + p["b"]
        if "g" not in p:
            return h
        if stats is not None:
            mu, var = stats[name]["mean"], stats[name]["var"]
        else:
            mu, var = jnp.mean(h, axis=(0, 1, 2)), jnp.var(h, axis=(0, 1, 2))
            if batch_stats is not None:
                batch_stats[name] = {"mean": mu, "var": var}
        return (h - mu) * (p["g"] * lax.rsqrt(var + BN_EPS)) + p["beta"]

    def pool(h):  # noqa: ANN001, ANN202
        return lax.reduce_window(h, -jnp.inf, lax.max, (1, 2, 2, 1), (1, 2, 2, 1), "VALID")

    def up(h):  # noqa: ANN001, ANN202
        return jnp.repeat(jnp.repeat(h, 2, axis=1), 2, axis=2)

    r = jax.nn.relu
    skips, h = [], x
    for k in range(1, scales_of(params) + 1):
        h = r(conv(f"e{k}b", r(conv(f"e{k}a", pool(h) if k > 1 else h))))
        skips.append(h)
    for k in range(len(skips) - 1, 0, -1):
        h = r(conv(f"d{k}", jnp.concatenate([up(h), skips[k - 1]], axis=-1)))
    return conv("head", h)


def loss_fn(params, x, y, pos_weight: float = 1.0, dice_weight: float = 1.0):  # noqa: ANN001, ANN201
    """Mean binary cross-entropy (crack pixels weighted ``pos_weight``) plus ``dice_weight`` times the soft
    Dice loss (1 - 2|P∩Y| / (|P| + |Y|), i.e. one minus a soft F-measure) over the batch; also the batch's
    normalisation statistics (empty without batch norm)."""
    import jax
    import jax.numpy as jnp

    batch_stats: dict = {}
    z = forward(params, x, batch_stats=batch_stats)[..., 0]
    sp_neg = jnp.log1p(jnp.exp(-jnp.abs(z)))  # log(1 + e^-|z|)
    # -log sigmoid(z) = max(-z, 0) + sp_neg; -log(1 - sigmoid(z)) = max(z, 0) + sp_neg
    bce = jnp.mean(pos_weight * y * (jnp.maximum(-z, 0) + sp_neg) + (1 - y) * (jnp.maximum(z, 0) + sp_neg))
    p = jax.nn.sigmoid(z)
    dice = 1 - (2 * jnp.sum(p * y) + 1) / (jnp.sum(p) + jnp.sum(y) + 1)
    return bce + dice_weight * dice, batch_stats


def pad_to(x: np.ndarray, multiple: int) -> tuple[np.ndarray, int, int]:
    """``x`` padded (reflected) to multiples of ``multiple`` (the network's total pooling), its height and width."""
    h, w = x.shape
    ph, pw = (-h) % multiple, (-w) % multiple
    return (np.pad(x, ((0, ph), (0, pw)), mode="reflect") if ph or pw else x), h, w


def f_exact(pred: np.ndarray, gt: np.ndarray) -> float:
    """Defect-class F with exact pixels (same empty-case rule as services.detector.metrics)."""
    tp = np.count_nonzero(pred & gt)
    np_, ng = np.count_nonzero(pred), np.count_nonzero(gt)
    p = tp / np_ if np_ else (1.0 if ng == 0 else 0.0)
    r = tp / ng if ng else (1.0 if np_ == 0 else 0.0)
    return 2 * p * r / (p + r) if p + r else 0.0


def validate(predict, val) -> dict[str, float]:  # noqa: ANN001
    """Mean exact F on the validation images at every threshold of :data:`THRESHOLDS`."""
    probs = [predict(g) for _, g, _ in val]
    return {f"{t:.2f}": float(np.mean([f_exact(p > t, m) for p, (_, _, m) in zip(probs, val)])) for t in THRESHOLDS}


def train(a: argparse.Namespace) -> int:
    import jax
    import jax.numpy as jnp
    import optax

    root, out = Path(a.data), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(a.seed)
    widths = tuple(a.widths)
    most = STRIDE.bit_length()  # the runtime pads frames to STRIDE: 2 ** (scales - 1) must divide it
    if not 2 <= len(widths) <= most or min(widths) < 1 or a.crop % 2 ** (len(widths) - 1):
        raise SystemExit(f"train_detector: --widths takes 2 to {most} positive channel counts and --crop a multiple "
                         f"of 2 ** (scales - 1), got {list(widths)} and {a.crop}")
    if not 0 <= a.wide_cracks <= 1:
        raise SystemExit(f"train_detector: --wide-cracks takes a probability in [0, 1], got {a.wide_cracks}")
    if not 0.1 <= a.scale[0] <= a.scale[1] <= 4:
        raise SystemExit(f"train_detector: --scale takes LO <= HI within 0.1-4, got {a.scale[0]} {a.scale[1]}")
    tr = [s for d in DATASETS for s in load_pairs(root, d, "train", a.limit)]
    val = [s for d in DATASETS for s in load_pairs(root, d, "val", a.limit)]
    walls = wall_pairs(a.walls) if a.walls else []
    tr += walls
    log.info("train %d images (%d of synthetic walls), validation %d images", len(tr), len(walls), len(val))
    if a.init:
        if a.norm != "none":
            raise SystemExit("train_detector: --init starts from an exported model, which has no batch norm to train")
        p0, widths = onnx_params(Path(a.init))
    else:
        p0 = init_params(a.seed, widths, a.norm == "batch")
    params = jax.tree_util.tree_map(jnp.asarray, p0)
    stats = jax.tree_util.tree_map(jnp.asarray, init_stats(params))
    steps_per_epoch = max(1, (len(tr) * a.crops_per_image) // a.batch)
    sched = optax.cosine_onecycle_schedule(a.epochs * steps_per_epoch, a.lr, pct_start=0.1)
    opt = optax.adamw(sched, weight_decay=1e-4)
    state = opt.init(params)

    @jax.jit
    def step(params, state, stats, x, y):  # noqa: ANN001, ANN202
        (loss, bs), g = jax.value_and_grad(loss_fn, has_aux=True)(params, x, y, a.pos_weight, a.dice_weight)
        upd, state = opt.update(g, state, params)
        stats = jax.tree_util.tree_map(lambda r, b: BN_MOMENTUM * r + (1 - BN_MOMENTUM) * b, stats, bs)
        return optax.apply_updates(params, upd), state, stats, loss

    fwd = jax.jit(lambda p, s, x: jax.nn.sigmoid(forward(p, x, stats=s)))

    @jax.jit
    def ema_update(ema, params):  # noqa: ANN001, ANN202
        return jax.tree_util.tree_map(lambda e, p: a.ema * e + (1 - a.ema) * p, ema, params)

    @jax.jit
    def batch_norm_stats(params, x):  # noqa: ANN001, ANN202
        bs: dict = {}
        forward(params, x, batch_stats=bs)
        return bs

    bn_rng = np.random.default_rng(a.seed + 1)  # apart from the training stream, so --ema leaves it as it was

    def recomputed_stats(p):  # noqa: ANN001, ANN202
        """Batch-norm statistics of the averaged weights: the mean of :data:`BN_BATCHES` training batches' own
        (the running statistics belong to the weights being trained, not to their average)."""
        got = []
        for _ in range(BN_BATCHES):
            idx = bn_rng.integers(len(tr), size=a.batch)
            xs, _ = zip(*(augment(bn_rng, tr[k][1], tr[k][2], a.crop, a.scale) for k in idx))
            got.append(batch_norm_stats(p, jnp.asarray(np.stack(xs)[..., None])))
        return jax.tree_util.tree_map(lambda *v: jnp.mean(jnp.stack(v), axis=0), *got)

    def predict_with(p, s, flip: bool = False):  # noqa: ANN001, ANN202
        def predict(g: np.ndarray) -> np.ndarray:
            x, h, w = pad_to(standardise(g), 2 ** (len(widths) - 1))
            y = np.asarray(fwd(p, s, x[None, :, :, None]))[0, :, :, 0]
            if flip:  # test-time horizontal flip: the mean of the two probability maps
                y = 0.5 * (y + np.asarray(fwd(p, s, np.ascontiguousarray(x[:, ::-1])[None, :, :, None]))[0, :, ::-1, 0])
            return y[:h, :w]
        return predict

    run: dict[str, object] = {
        "seed": a.seed, "widths": widths, "norm": a.norm, "crop": a.crop, "scale": list(a.scale), "batch": a.batch,
        "lr": a.lr,
        "pos_weight": a.pos_weight, "dice_weight": a.dice_weight, "wide_cracks": a.wide_cracks, "ema": a.ema,
        "init": Path(a.init).name if a.init else None,
        "walls": {"scenario": "monorail", "seeds": a.walls, "images": len(walls)},
        "epochs_planned": a.epochs, "crops_per_image": a.crops_per_image, "minutes_budget": a.minutes,
        "split": {"rule": splits.__doc__, "train": len(tr), "val": len(val)}, "epochs": [],
    }
    best = (-1.0, None, None, -1, None)
    ema = params if a.ema else None
    t0 = time.monotonic()
    for ep in range(a.epochs):
        order = rng.permutation(np.repeat(np.arange(len(tr)), a.crops_per_image))
        losses = []
        for i in range(steps_per_epoch):
            idx = order[i * a.batch:(i + 1) * a.batch]
            xs, ys = zip(*(augment(rng, tr[k][1], tr[k][2], a.crop, a.scale) for k in idx))
            if a.wide_cracks:
                xs, ys = zip(*(paint_wide_crack(rng, xi, yi) if rng.random() < a.wide_cracks else (xi, yi)
                               for xi, yi in zip(xs, ys)))
            params, state, stats, loss = step(params, state, stats, jnp.asarray(np.stack(xs)[..., None]),
                                              jnp.asarray(np.stack(ys)))
            losses.append(float(loss))
            if ema is not None:
                ema = ema_update(ema, params)
        if ema is not None:  # the weights' moving average is what is validated, chosen and exported
            params_v, stats_v = ema, (recomputed_stats(ema) if stats else stats)
        else:
            params_v, stats_v = params, stats
        fs = validate(predict_with(params_v, stats_v), val)
        t_best = max(fs, key=fs.get)
        row = {"epoch": ep + 1, "loss": float(np.mean(losses)), "val_f": fs[t_best], "val_threshold": float(t_best),
               "minutes": (time.monotonic() - t0) / 60}
        run["epochs"].append(row)
        log.info("epoch %d: loss %.4f, validation exact F %.4f at %s (%.1f min)", ep + 1, row["loss"], fs[t_best],
                 t_best, row["minutes"])
        if fs[t_best] > best[0]:
            best = (fs[t_best], jax.tree_util.tree_map(np.asarray, params_v), float(t_best), ep + 1,
                    jax.tree_util.tree_map(np.asarray, stats_v))
            np.savez(out / "crack_unet_best.npz", **{f"{k}.{j}": v for k, d in best[1].items() for j, v in d.items()},
                     **{f"{k}.bn_{j}": v for k, d in best[4].items() for j, v in d.items()})
        (out / "train_run.json").write_text(json.dumps(run, indent=1))
        if a.minutes and row["minutes"] > a.minutes:
            log.info("time budget of %.0f min reached", a.minutes)
            break
    run["best"] = {"epoch": best[3], "val_f": best[0], "threshold": best[2]}
    pb, sb = (jax.tree_util.tree_map(jnp.asarray, t) for t in (best[1], best[4]))
    fs_flip = validate(predict_with(pb, sb, flip=True), val)
    run["best"]["val_f_flip"] = max(fs_flip.values())  # test-time flip, measured on validation, not shipped
    folded = fold_batch_norm(best[1], best[4])
    path = export_onnx(folded, best[2], out / a.name, widths)
    x = np.random.default_rng(1).normal(size=(1, 64, 96, 1)).astype(np.float32)
    ref = np.asarray(fwd(pb, sb, x))[0, :, :, 0]
    got = onnx_probe(path, x[0, :, :, 0], best[2])
    run["export_max_abs_diff"] = float(np.max(np.abs(ref - got)))
    run["onnx"] = {"file": path.name, "bytes": path.stat().st_size}
    (out / "train_run.json").write_text(json.dumps(run, indent=1))
    log.info("wrote %s (%d bytes; cv2.dnn vs JAX max |diff| %.2e; validation F %.4f, with test-time flip %.4f) and %s",
             path, path.stat().st_size, run["export_max_abs_diff"], best[0], run["best"]["val_f_flip"],
             out / "train_run.json")
    return 0


def fold_batch_norm(params: dict[str, dict[str, np.ndarray]],
                    stats: dict[str, dict[str, np.ndarray]]) -> dict[str, dict[str, np.ndarray]]:
    """Plain convolutions equal to conv + batch norm at inference: ``w' = w s``, ``b' = (b - mean) s + beta``
    with ``s = g / sqrt(var + eps)`` per output channel (Ioffe & Szegedy 2015, Sec. 3.2)."""
    out = {}
    for k, p in params.items():
        if "g" not in p:
            out[k] = {"w": np.asarray(p["w"], np.float32), "b": np.asarray(p["b"], np.float32)}
            continue
        s = np.asarray(p["g"], np.float64) / np.sqrt(np.asarray(stats[k]["var"], np.float64) + BN_EPS)
        out[k] = {"w": (np.asarray(p["w"], np.float64) * s).astype(np.float32),
                  "b": ((np.asarray(p["b"], np.float64) - stats[k]["mean"]) * s + p["beta"]).astype(np.float32)}
    return out


# ---------------------------------------------------------------- export (onnx helper API)
def export_onnx(params: dict[str, dict[str, np.ndarray]], threshold: float, path: Path,
                widths: tuple[int, ...] = WIDTHS) -> Path:
    """The network as an ONNX graph (opset 13, NCHW, input ``x`` (1, 1, H, W) standardised grey, output ``p``
    (1, 1, H, W) crack probability with ``threshold`` folded into the head so that ``p > 0.5`` is the cut)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    inits, nodes = [], []

    def const(name: str, arr: np.ndarray) -> str:
        inits.append(numpy_helper.from_array(arr, name))
        return name

    def conv(name: str, x: str, relu: bool = True) -> str:
        w = np.ascontiguousarray(params[name]["w"].transpose(3, 2, 0, 1))  # HWIO -> OIHW
        b = params[name]["b"].astype(np.float32)
        if name == "head":
            b = b - np.float32(math.log(threshold / (1 - threshold)))
        k = w.shape[2] // 2
        nodes.append(helper.make_node("Conv", [x, const(f"{name}.w", w), const(f"{name}.b", b)], [f"{name}.c"],
                                      kernel_shape=list(w.shape[2:]), pads=[k, k, k, k], strides=[1, 1]))
        if not relu:
            return f"{name}.c"
        nodes.append(helper.make_node("Relu", [f"{name}.c"], [f"{name}.r"]))
        return f"{name}.r"

    def pool(x: str) -> str:
        nodes.append(helper.make_node("MaxPool", [x], [f"{x}.p"], kernel_shape=[2, 2], strides=[2, 2]))
        return f"{x}.p"

    scales = const("up.scales", np.array([1, 1, 2, 2], np.float32))

    def up_cat(x: str, skip: str) -> str:
        nodes.append(helper.make_node("Resize", [x, "", scales], [f"{x}.u"], mode="nearest",
                                      coordinate_transformation_mode="asymmetric", nearest_mode="floor"))
        nodes.append(helper.make_node("Concat", [f"{x}.u", skip], [f"{x}.cat"], axis=1))
        return f"{x}.cat"

    skips, h = [], "x"
    for k in range(1, len(widths) + 1):
        h = conv(f"e{k}b", conv(f"e{k}a", pool(h) if k > 1 else h))
        skips.append(h)
    for k in range(len(widths) - 1, 0, -1):
        h = conv(f"d{k}", up_cat(h, skips[k - 1]))
    nodes.append(helper.make_node("Sigmoid", [conv("head", h, relu=False)], ["p"]))
    graph = helper.make_graph(
        nodes, "crack_unet",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 1, "H", "W"])],
        [helper.make_tensor_value_info("p", TensorProto.FLOAT, [1, 1, "H", "W"])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)], producer_name="skynet-train")
    model.ir_version = 8
    model.doc_string = f"crack U-Net {'-'.join(map(str, widths))}; p > 0.5 is a crack pixel (threshold {threshold:.2f})"
    onnx.checker.check_model(model)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(model, str(path))
    return path


def onnx_probe(path: Path, x: np.ndarray, threshold: float) -> np.ndarray:
    """The exported model's probability on ``x`` (H, W) through ``cv2.dnn``, un-folding ``threshold`` so it
    compares with the JAX forward pass."""
    net = cv2.dnn.readNetFromONNX(str(path))
    net.setInput(x[None, None].astype(np.float32))
    p = np.clip(net.forward()[0, 0].astype(np.float64), 1e-7, 1 - 1e-7)
    z = np.log(p / (1 - p)) + math.log(threshold / (1 - threshold))
    return 1 / (1 + np.exp(-z))


# ---------------------------------------------------------------- evaluation
def evaluate_held_out(a: argparse.Namespace) -> int:
    """Score the shipped model and ``it+r`` on both held-out test folds; write ``eval_<dataset>.md/.json``."""
    import os

    if a.model:
        os.environ["SKYNET_DETECTOR_MODEL"] = str(Path(a.model).resolve())
    import platform
    import subprocess

    from services.detector.evaluate import Sample, evaluate, write_results

    model = Path(os.environ.get("SKYNET_DETECTOR_MODEL") or ROOT / "services" / "detector" / "models" / "crack_unet.onnx")
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT,
                          check=False).stdout.strip()
    summary: dict[str, object] = {"meta": {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "commit": head or "?",
        "machine": f"{platform.machine()}, {os.cpu_count()} cores (shared), load average {os.getloadavg()[0]:.1f}",
        "command": "scripts/train_detector.py evaluate --data DATA" + (" --model MODEL" if a.model else "")
                   + (" --out OUT" if a.out else "") + " --methods " + " ".join(a.methods), "model": model.name,
        "model_bytes": model.stat().st_size if model.is_file() else None}}
    for d in DATASETS:
        samples = [Sample(n, g, np.where(m, 255, 0).astype(np.uint8)) for n, g, m in load_pairs(Path(a.data), d, "test")]
        ev = evaluate(samples, a.methods, dataset=f"{d} (held-out test fold)")
        if a.out:
            write_results(ev, a.out, stem=f"eval_{d}")
        summary[d] = {"images": len(samples), **ev.mean}
        for m, r in ev.mean.items():
            print(f"{d:16s} {m:8s} F {r['f']:.4f}  F(2px) {r['f_tol']:.4f}  P {r['precision']:.4f}  "
                  f"R {r['recall']:.4f}  {r['ms']:.1f} ms")
    if a.out:
        (Path(a.out) / "eval_summary.json").write_text(json.dumps(summary, indent=1))
    return 0


#: the flat dark bands a probe model is shown (px), as the wide-crack guard of tests/services/detector/test_learned.py
BANDS = (3, 5, 7, 9, 11)


def probe_wide(a: argparse.Namespace) -> int:
    """How much of a wide crack a model sees (the probes' second bar, docs/detector.md): the share of a flat dark
    band on a noisy wall taken as crack, per width of :data:`BANDS`, and the share of the pixels of cracks 7-11 px
    wide painted (:func:`paint_wide_crack`) on the validation photographs that are found; printed and, with
    ``--out``, written as JSON. No training framework needed."""
    from services.detector.learned import probability

    model = str(Path(a.model).resolve()) if a.model else None
    rng = np.random.default_rng(0)
    wall = np.clip(170 + rng.normal(0, 8, (160, 240)), 0, 255).astype(np.uint8)
    bands = {}
    for w in BANDS:
        g = wall.copy()
        top = 80 - w // 2
        g[top:top + w, 50:178] = 60
        bands[str(w)] = float(np.mean(probability(g, model)[top:top + w, 60:168] > 0.5))
    rng = np.random.default_rng(11)
    found = []
    for _, g, m in [s for d in DATASETS for s in load_pairs(Path(a.data), d, "val")][:a.images]:
        x = standardise(g)
        y, mm = paint_wide_crack(rng, x, m.astype(np.float32), width=(7, 11))
        painted = (mm > 0) & ~m
        shown = np.clip(float(g.mean()) + y * (float(g.std()) + 1.0), 0, 255).astype(np.uint8)
        found.append(float(np.mean(probability(shown, model)[painted] > 0.5)))
    doc = {"model": Path(model).name if model else "shipped", "flat_band_share_by_width_px": bands,
           "painted_7_11px_found": float(np.mean(found)) if found else None, "painted_images": len(found)}
    print(json.dumps(doc))
    if a.out:
        Path(a.out).write_text(json.dumps(doc, indent=1))
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="train_detector.py", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    t = sub.add_parser("train", help="train and export the model")
    t.add_argument("--data", required=True, help="folder holding crackforest/ and deepcrack-train/")
    t.add_argument("--out", required=True, help="folder for the ONNX model, train_run.json and the best weights")
    t.add_argument("--name", default="crack_unet.onnx")
    t.add_argument("--seed", type=int, default=7)
    t.add_argument("--epochs", type=int, default=36)
    t.add_argument("--minutes", type=float, default=0, help="stop after the epoch that passes this wall time")
    t.add_argument("--crop", type=int, default=128)
    t.add_argument("--scale", type=float, nargs=2, default=list(SCALE), metavar=("LO", "HI"),
                   help="range of the random scale a training image is drawn at (log-uniform; above 1 draws "
                        "its cracks wider)")
    t.add_argument("--batch", type=int, default=16)
    t.add_argument("--crops-per-image", type=int, default=2)
    t.add_argument("--lr", type=float, default=3e-3)
    t.add_argument("--widths", type=int, nargs="+", default=list(WIDTHS), metavar="C",
                   help=f"channels per scale, one scale per value, 2 to {STRIDE.bit_length()} of them "
                        "(default %(default)s)")
    t.add_argument("--norm", choices=("none", "batch"), default="none",
                   help="batch norm after every convolution but the head (folded into it on export)")
    t.add_argument("--init", help="start from this exported ONNX model (fine-tuning) instead of a random one")
    t.add_argument("--walls", type=int, nargs="*", default=[], metavar="SEED",
                   help="also train on the monorail scenario's synthetic wall made with these texture seeds")
    t.add_argument("--ema", type=float, default=0.0, metavar="D",
                   help="validate, choose and export the exponential moving average of the weights, decay D per "
                        "step (Polyak averaging; 0: the weights themselves)")
    t.add_argument("--pos-weight", type=float, default=1.0, help="weight of crack pixels in the cross-entropy")
    t.add_argument("--wide-cracks", type=float, default=0.0, metavar="P",
                   help="paint a crack 4-14 px wide on each training crop with probability P (paint_wide_crack)")
    t.add_argument("--dice-weight", type=float, default=1.0, help="weight of the soft Dice term")
    t.add_argument("--limit", type=int, help="only the first N images of each split (a smoke run)")
    e = sub.add_parser("evaluate", help="score the model and it+r on the held-out test folds")
    e.add_argument("--data", required=True)
    e.add_argument("--model", help="ONNX file (default: the shipped one)")
    e.add_argument("--methods", nargs="+", default=["learned", "it+r"])
    e.add_argument("--out", help="folder for eval_<dataset>.md/.json and eval_summary.json")
    w = sub.add_parser("probe", help="how much of a wide crack a model sees: flat bands, painted wide cracks")
    w.add_argument("--data", required=True)
    w.add_argument("--model", help="ONNX file (default: the shipped one)")
    w.add_argument("--images", type=int, default=30, help="validation photographs painted on")
    w.add_argument("--out", help="JSON file of the figures")
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    return {"train": train, "evaluate": evaluate_held_out, "probe": probe_wide}[a.command](a)


if __name__ == "__main__":
    raise SystemExit(main())
