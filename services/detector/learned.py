"""The learned crack detector: a small U-Net shipped as ONNX and run by OpenCV's ``cv2.dnn``.

Design notes: docs/detector.md (services/detector/learned.py).
"""

from __future__ import annotations

import functools
import importlib.util
import logging
import os
import re
import threading
from pathlib import Path

import cv2
import numpy as np

from .thresholds import as_grey_u8

__all__ = ["MODEL_ENV", "MODEL_PATH", "RUNTIME_ENV", "RUNTIMES", "ModelError", "contrast_filter", "learned_mask",
           "load_model", "model_path", "probability", "runtime", "splits", "warm_up"]

log = logging.getLogger(__name__)

MODEL_PATH = Path(__file__).resolve().with_name("models") / "crack_unet.onnx"
MODEL_ENV = "SKYNET_DETECTOR_MODEL"
RUNTIME_ENV = "SKYNET_DETECTOR_RUNTIME"
RUNTIMES = ("opencv", "openvino")
#: input sizes (h, w) a detector worker's warm-up runs, so that OpenVINO's per-shape kernels are built
#: before the first capture (0.3 s at 480 x 640, 1.4 s at 752 x 1000): the nominal 640 x 480 frame and a 12 MP
#: capture's 1/4 decode
WARM_SHAPES = ((480, 640), (752, 1000))
#: inputs are padded to a multiple of this: a network of up to five scales (four poolings) sees whole cells
STRIDE = 16
#: frames above this many pixels are segmented in tiles of TILE x TILE (plus margins)
TILE_PX = 2_000_000
TILE = 1024
TILE_MARGIN = 32
#: :func:`contrast_filter`'s defaults, chosen on the validation split (never the test folds) and the
#: synthetic walls of texture seeds 7, 11 and 13 (never the mission's own)
CONTRAST_REL = 0.2
CONTRAST_FLOOR = 0.02
CONTRAST_RING = 3
#: a larger file is not this model (the shipped one is well under 1 MB)
MAX_MODEL_BYTES = 64 * 1024 * 1024

_cache: dict[str, cv2.dnn.Net] = {}
_ov_cache: dict[tuple[str, int], object] = {}
_lock = threading.Lock()  # a cv2.dnn.Net is not safe to run from two threads at once


class ModelError(RuntimeError):
    """The learned detector's model file is missing or not a usable model (message: one line, naming it)."""


def model_path() -> Path:
    """The model file in use: ``$SKYNET_DETECTOR_MODEL`` when set, else the shipped :data:`MODEL_PATH`."""
    env = os.environ.get(MODEL_ENV, "").strip()
    return Path(env) if env else MODEL_PATH


def _probe(net: cv2.dnn.Net, where: Path) -> None:
    """Run the net on a small frame: it must give one probability per pixel."""
    shape = (1, 1, STRIDE, 2 * STRIDE)
    net.setInput(np.zeros(shape, np.float32))
    out = net.forward()
    if out.shape != shape or not np.all(np.isfinite(out)):
        raise ModelError(f"learned detector model {where}: not a crack segmentation model "
                         f"(output {tuple(out.shape)} for a {'x'.join(map(str, shape))} input)")


def load_model(path: str | Path | None = None) -> cv2.dnn.Net:
    """The ``cv2.dnn`` network of ``path`` (default :func:`model_path`), read and checked once per process."""
    p = Path(path) if path is not None else model_path()
    key = str(p.resolve()) if p.exists() else str(p)
    with _lock:
        if key in _cache:
            return _cache[key]
        if not p.is_file():
            raise ModelError(f"learned detector model {p}: no such file")
        size = p.stat().st_size
        if size == 0 or size > MAX_MODEL_BYTES:
            raise ModelError(f"learned detector model {p}: {size} bytes is not a model file")
        try:
            net = cv2.dnn.readNetFromONNX(str(p))
        except cv2.error as exc:
            why = re.search(r"error: \([^)]*\) (.*?)(?: in function .*)?$", str(exc).strip().splitlines()[-1])
            reason = (why.group(1) if why else "unreadable").replace(f": {p}", "")[:160]
            raise ModelError(f"learned detector model {p}: not a readable ONNX model (OpenCV: {reason})") from None
        if net.empty():
            raise ModelError(f"learned detector model {p}: empty network")
        try:
            _probe(net, p)
        except cv2.error:
            raise ModelError(f"learned detector model {p}: the network does not run on a grey image") from None
        net.setPreferableBackend(cv2.dnn.DNN_BACKEND_OPENCV)
        _cache[key] = net
        log.info("learned detector model %s loaded (%d bytes)", p, size)
        return net


@functools.cache
def _has_openvino() -> bool:
    return importlib.util.find_spec("openvino") is not None


def runtime() -> str:
    """The runtime the network runs on: ``$SKYNET_DETECTOR_RUNTIME`` when set, else ``openvino`` when that
    package is installed, else ``opencv``. A name not in :data:`RUNTIMES`, or ``openvino`` without the
    package, is a :class:`ModelError` (one line)."""
    env = os.environ.get(RUNTIME_ENV, "").strip().lower()
    if env and env not in RUNTIMES:
        raise ModelError(f"learned detector runtime {env!r} (${RUNTIME_ENV}): choose from {', '.join(RUNTIMES)}")
    has_ov = _has_openvino()
    if env == "openvino" and not has_ov:
        raise ModelError(f"learned detector runtime openvino (${RUNTIME_ENV}): not installed "
                         "(pip install -e '.[fast]')")
    return env or ("openvino" if has_ov else "opencv")


def _openvino(path: Path) -> object:
    """An OpenVINO infer request of the model at ``path`` (dynamic input size), compiled once per process
    and OpenCV thread count: bfloat16 where the CPU computes it natively (OpenVINO's own choice: elsewhere
    float32), no thread pinning (the cores are shared)."""
    threads = max(1, cv2.getNumThreads())
    key = (str(path.resolve()), threads)
    if key not in _ov_cache:
        import openvino as ov

        core = ov.Core()
        try:
            compiled = core.compile_model(core.read_model(str(path)), "CPU", {
                "INFERENCE_NUM_THREADS": threads, "INFERENCE_PRECISION_HINT": "bf16", "ENABLE_CPU_PINNING": False})
        except RuntimeError as exc:
            first = (str(exc).strip().splitlines() or ["unreadable"])[0][:160]
            raise ModelError(f"learned detector model {path}: OpenVINO cannot compile it ({first})") from None
        _ov_cache[key] = compiled.create_infer_request()
        log.info("learned detector model %s compiled by OpenVINO (%d threads)", path, threads)
    return _ov_cache[key]


def _run(net: cv2.dnn.Net, x: np.ndarray, model: str | Path | None = None) -> np.ndarray:
    """Probability map of one standardised float32 block (any size; padded to :data:`STRIDE`) on
    :func:`runtime`'s engine (``net`` is the checked ``cv2.dnn`` network of ``model``)."""
    h, w = x.shape
    ph, pw = (-h) % STRIDE, (-w) % STRIDE
    if ph or pw:
        x = cv2.copyMakeBorder(x, 0, ph, 0, pw, cv2.BORDER_REPLICATE)
    with _lock:
        if runtime() == "openvino":
            req = _openvino(Path(model) if model is not None else model_path())
            req.infer({0: x[None, None]})  # type: ignore[attr-defined]
            return np.array(req.get_output_tensor(0).data[0, 0, :h, :w])  # type: ignore[attr-defined]
        net.setInput(x[None, None])
        out = net.forward()
    return out[0, 0, :h, :w]


def warm_up(model: str | Path | None = None, shapes: tuple[tuple[int, int], ...] = WARM_SHAPES) -> str:
    """Load the model and run it once on each of ``shapes`` (a detector worker's start); the runtime's name."""
    name = runtime()  # a wrong runtime first: its one line alone
    net = load_model(model)
    for h, w in shapes:
        _run(net, np.zeros((h, w), np.float32), model)
    return name


def probability(grey: np.ndarray, model: str | Path | None = None) -> np.ndarray:
    """Crack probability (float32, the image's shape) of a grey (or BGR) image; ``> 0.5`` is a crack."""
    g = as_grey_u8(grey)
    net = load_model(model)
    x = g.astype(np.float32)
    x = (x - float(x.mean())) / (float(x.std()) + 1.0)
    H, W = x.shape
    if H * W <= TILE_PX:
        return _run(net, x, model)
    out = np.empty((H, W), np.float32)
    m = TILE_MARGIN
    for y0 in range(0, H, TILE):
        for x0 in range(0, W, TILE):
            y1, x1 = min(H, y0 + TILE), min(W, x0 + TILE)
            ya, xa = max(0, y0 - m), max(0, x0 - m)
            p = _run(net, np.ascontiguousarray(x[ya:min(H, y1 + m), xa:min(W, x1 + m)]), model)
            out[y0:y1, x0:x1] = p[y0 - ya:y0 - ya + (y1 - y0), x0 - xa:x0 - xa + (x1 - x0)]
    return out


def contrast_filter(grey: np.ndarray, mask: np.ndarray, rel: float = CONTRAST_REL, floor: float = CONTRAST_FLOOR,
                    ring: int = CONTRAST_RING) -> np.ndarray:
    """The components (8-connected) of ``mask`` that are darker than their surround all round, as a uint8 0/255
    mask (the one-sided contrast: docs/detector.md, services/detector/learned.py)."""
    m = mask > 0
    n, lab, st, _ = cv2.connectedComponentsWithStats(m.astype(np.uint8), connectivity=8)
    if n <= 1:
        return np.zeros(m.shape, np.uint8)
    g = grey.astype(np.float32)
    k = np.ones((2 * ring + 1, 2 * ring + 1), np.uint8)
    H, W = m.shape
    c = np.zeros(n, np.float64)
    for i in range(1, n):
        x, y, w, h = (int(v) for v in st[i, :4])
        y0, x0, y1, x1 = max(0, y - ring), max(0, x - ring), min(H, y + h + ring), min(W, x + w + ring)
        comp = lab[y0:y1, x0:x1] == i
        band = cv2.dilate(comp.astype(np.uint8), k).astype(bool) & ~m[y0:y1, x0:x1]
        if not band.any():
            continue  # no background around it (a component filling its surround): no evidence of a valley
        gs = g[y0:y1, x0:x1]
        mu, q = float(gs[comp].mean()), float(np.percentile(gs[band], 25))
        c[i] = (q - mu) / (q + mu) if q + mu > 0 else 0.0
    keep = c >= max(floor, rel * float(c.max()))
    keep[0] = False
    return np.where(keep[lab], 255, 0).astype(np.uint8)


def learned_mask(grey: np.ndarray, model: str | Path | None = None) -> tuple[np.ndarray, None]:
    """Mask (uint8 0/255) of the pixels the network gives a crack probability above 0.5 that form valleys
    (:func:`contrast_filter`); no global threshold."""
    g = as_grey_u8(grey)
    return contrast_filter(g, np.where(probability(g, model) > 0.5, 255, 0).astype(np.uint8)), None


def splits(names: list[str], dataset: str) -> dict[str, list[str]]:
    """The shipped model's fixed train / val / test split of one data set's image names, by sorted index ``i``.

    test (never trained on nor used for model selection): CrackForest ``i`` odd (its even-numbered half,
    the half IT+r's parameters were not chosen on), any other set ``i % 5 == 4`` (a fifth); of the rest,
    by index ``j``: val ``j % 8 == 7`` (choice of epoch and threshold), train the others."""
    names = sorted(names)
    if dataset == "crackforest":
        test = [n for i, n in enumerate(names) if i % 2 == 1]
    else:
        test = [n for i, n in enumerate(names) if i % 5 == 4]
    held = set(test)
    rest = [n for n in names if n not in held]
    return {"train": [n for j, n in enumerate(rest) if j % 8 != 7],
            "val": [n for j, n in enumerate(rest) if j % 8 == 7], "test": test}
