"""The NDRF shader in PyTorch: the differentiable twin of
:func:`clrender.ndrf.shader_ref.shade_reference` (docs/ndrf.md), used for training.

Per-vertex features are parameters gathered by barycentric weights; hit positions and the
view encoding are constants of a view; the two conv layers follow docs/ndrf.md's alternated
padding (also on patches, computed with a 1-pixel halo and cropped).

Examples:
    >>> shader = NDRFShader.from_model(model)            # from an NDRFModel
    >>> rgb = shade_image(shader, tri, bary, dirs, background)   # (H, W, 3)
    >>> arrays = shader.to_arrays(background)            # back to baked arrays
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..ngprt.torch_ops import weighted_gather
from .baked import NDRFModel
from .config import NDRFConfig
from .hits import HitCaster
from .view_memory import DISK_BACKED_VIEW_BYTES, disk_arrays, view_budget

F32 = np.float32


def view_encoding(dirs: torch.Tensor, n_freq: int) -> torch.Tensor:
    """(..., 3) unit directions -> (..., 3 + 6 n_freq): d, then sin(2^i d), cos(2^i d)."""
    parts = [dirs]
    for i in range(n_freq):
        a = float(2.0 ** i) * dirs
        parts += [torch.sin(a), torch.cos(a)]
    return torch.cat(parts, -1)


def crop(tri, bary, y0: int, x0: int, ph: int, pw: int, halo: int):
    """The hits of pixels [y0 - halo, y0 + ph + halo) x [x0 - halo, x0 + pw + halo).

    Args:
        tri: (K, H, W) int tensor, -1 = miss; bary: (K, H, W, 2) float32.
    Returns:
        tri (K, R, C) int64 (-1 also outside the image), bary (K, R, C, 2), inside (R, C)
        bool (the pixel lies in the image), rows (R,) and cols (C,) clamped to the image,
        with R = ph + 2 halo, C = pw + 2 halo.
    """
    H, W = tri.shape[1:]
    rows = torch.arange(y0 - halo, y0 + ph + halo, device=tri.device)
    cols = torch.arange(x0 - halo, x0 + pw + halo, device=tri.device)
    inside = ((rows >= 0) & (rows < H))[:, None] & ((cols >= 0) & (cols < W))[None, :]
    rows, cols = rows.clamp(0, H - 1), cols.clamp(0, W - 1)
    t = tri[:, rows][:, :, cols].long()
    return torch.where(inside, t, -1), bary[:, rows][:, :, cols], inside, rows, cols


def camera_dirs(cam: torch.Tensor, rows: torch.Tensor, cols: torch.Tensor) -> torch.Tensor:
    """(R, C, 3) float32 unit ray directions of pixels rows x cols of a packed camera
    (``Camera.packed()``, (16,) float32), in the operation order of ``generate_rays``."""
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    R = cam[4:13].reshape(3, 3)
    a = ((cols.float() + 0.5 - cx) / fx)[None, :].expand(len(rows), len(cols))
    b = (-((rows.float() + 0.5 - cy) / fy))[:, None].expand(len(rows), len(cols))
    d = [R[i, 0] * a + R[i, 1] * b - R[i, 2] for i in range(3)]
    norm = torch.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    return torch.stack([di / norm for di in d], -1)


class NDRFShader(torch.nn.Module):
    """Per-vertex features of K fixed meshes and the conv shader, differentiable.

    Parameters (the checkpoint's state dict): ``features.k`` (V_k, 8) and ``conv0``,
    ``conv1`` (torch layout (out, in, S, S)). Vertices and faces are fixed buffers.
    """

    def __init__(self, config: NDRFConfig, meshes, features, convs):
        super().__init__()
        self.config = config
        self.features = torch.nn.ParameterList(
            [torch.nn.Parameter(torch.as_tensor(np.asarray(f, F32))) for f in features])
        for k, (v, f) in enumerate(meshes):
            self.register_buffer(f"vertices_{k}", torch.as_tensor(np.asarray(v, F32)),
                                 persistent=False)
            self.register_buffer(f"faces_{k}", torch.as_tensor(np.asarray(f, np.int64)),
                                 persistent=False)
        S, H = config.kernel_size, config.hidden
        self.conv0 = torch.nn.Conv2d(config.c_in, H, S)
        self.conv1 = torch.nn.Conv2d(H, 3, S)
        # The screen buffer is built (R, C, C_in), i.e. channels-last: so are the convs
        # (on the CPU oneDNN then skips layout copies: CHANGELOG.md, "channels-last convs").
        self.conv0.to(memory_format=torch.channels_last)
        self.conv1.to(memory_format=torch.channels_last)
        with torch.no_grad():
            for conv, (w, b) in zip((self.conv0, self.conv1), convs):
                conv.weight.copy_(torch.as_tensor(np.transpose(w, (3, 2, 0, 1))))
                conv.bias.copy_(torch.as_tensor(b))

    @classmethod
    def from_model(cls, model: NDRFModel) -> "NDRFShader":
        """The shader of a (baked or initial) :class:`NDRFModel`."""
        K, a = model.config.K, model.arrays
        return cls(model.config, [model.mesh(k)[:2] for k in range(K)],
                   [model.mesh(k)[2] for k in range(K)],
                   [(a["conv0_w"], a["conv0_b"]), (a["conv1_w"], a["conv1_b"])])

    def to_arrays(self, background) -> dict:
        """The baked arrays (docs/ndrf.md): conv weights as [dy, dx, in, out]."""
        out = {}
        for k in range(self.config.K):
            out[f"vertices_{k}"] = getattr(self, f"vertices_{k}").cpu().numpy().astype(F32)
            out[f"faces_{k}"] = getattr(self, f"faces_{k}").cpu().numpy().astype(np.int32)
            out[f"features_{k}"] = self.features[k].detach().cpu().numpy().astype(F32)
        for i, conv in enumerate((self.conv0, self.conv1)):
            w = conv.weight.detach().cpu().numpy()
            out[f"conv{i}_w"] = np.ascontiguousarray(np.transpose(w, (2, 3, 1, 0)), F32)
            out[f"conv{i}_b"] = conv.bias.detach().cpu().numpy().astype(F32)
        out["background"] = np.asarray(background, F32).reshape(3)
        return out

    def screen_buffer(self, tri, bary, dirs, inside) -> torch.Tensor:
        """(R, C, C_in): features, hit positions, view encoding (zeros outside ``inside``).

        A pixel's three vertex rows are gathered with its barycentric weights in one fused
        pass per mesh (a miss weighs 0); the backward scatters into the features once.
        """
        R, C = tri.shape[1:]
        feats, pos = [], []
        for k in range(self.config.K):
            hit = (tri[k] >= 0).reshape(-1, 1).to(bary.dtype)
            idx = getattr(self, f"faces_{k}")[tri[k].clamp(min=0).reshape(-1)]      # (RC, 3)
            u, v = bary[k, ..., 0].reshape(-1, 1), bary[k, ..., 1].reshape(-1, 1)
            w = torch.cat([1.0 - u - v, u, v], 1) * hit                            # (RC, 3)
            feats.append(weighted_gather(self.features[k], idx, w))
            with torch.no_grad():
                pos.append(weighted_gather(getattr(self, f"vertices_{k}"), idx, w))
        view = view_encoding(dirs, self.config.n_freq) * inside[..., None]
        return torch.cat([t.reshape(R, C, -1) for t in feats + pos] + [view], -1)

    def forward(self, tri, bary, dirs, inside, background) -> torch.Tensor:
        """Shade a window of pixels with a halo of S - 1 pixels on every side.

        Args:
            tri (K, R, C) int64, -1 = miss; bary (K, R, C, 2); dirs (R, C, 3) unit ray
            directions; inside (R, C) bool (halo pixels outside the image: False), as
            :func:`crop` gives them; background (3,) RGB.
        Returns:
            (R - 2 (S - 1), C - 2 (S - 1), 3) composited RGB of the window's interior:
            layer 0 is a valid conv over the window (its bottom/right padding), its outputs
            outside the image are zeroed, then layer 1 (top/left padding), sigmoid.
        """
        halo = self.config.kernel_size - 1
        x = self.screen_buffer(tri, bary, dirs, inside).permute(2, 0, 1)[None]
        h = torch.relu(self.conv0(x))
        h = h * inside[:h.shape[2], :h.shape[3]]
        s = torch.sigmoid(self.conv1(h))[0].permute(1, 2, 0)
        R, C = tri.shape[1:]
        cov = (tri[:, halo:R - halo, halo:C - halo] >= 0).any(0)[..., None].to(s.dtype)
        return cov * s + (1.0 - cov) * background


def shade_image(shader: NDRFShader, tri, bary, dirs, background) -> torch.Tensor:
    """A full frame, as :func:`clrender.ndrf.shader_ref.shade_reference` (torch tensors:
    tri (K, H, W), bary (K, H, W, 2), dirs (H, W, 3); returns (H, W, 3))."""
    H, W = tri.shape[1:]
    halo = shader.config.kernel_size - 1
    t, b, inside, rows, cols = crop(tri, bary, 0, 0, H, W, halo)
    return shader(t, b, dirs[rows][:, cols], inside, torch.as_tensor(background))


def coverage_boxes(tri: np.ndarray) -> np.ndarray:
    """(N, 4) int64 ``(y0, x0, h, w)``: the bounding box of the pixels some mesh hits, per
    view of ``tri`` (N, K, H, W) (-1 = miss); the whole frame for a view with no hit."""
    cov = (np.asarray(tri) >= 0).any(axis=1)                       # (N, H, W)
    N, H, W = cov.shape
    boxes = np.tile(np.array([0, 0, H, W], np.int64), (N, 1))
    for n in range(N):
        rows, cols = np.flatnonzero(cov[n].any(1)), np.flatnonzero(cov[n].any(0))
        if len(rows):
            boxes[n] = rows[0], cols[0], rows[-1] + 1 - rows[0], cols[-1] + 1 - cols[0]
    return boxes


@dataclass
class ViewSet:
    """Views with their hits cast once: tri (N, K, H, W) int32, bary (N, K, H, W, 2)
    float32, images (N, H, W, 3) targets (the dtype given), cams (N, 16) packed cameras;
    boxes (N, 4) int64 numpy, :func:`coverage_boxes` of tri.

    In memory, every tensor is on the device; disk-backed (``disk_backed``), tri, bary and
    images are CPU tensors on memory-mapped files (pages read from disk when a step takes
    them, reclaimable cache) and only cams are on the device: :meth:`window` and
    :meth:`target` bring the part of the one view a step reads to the device."""

    tri: torch.Tensor
    bary: torch.Tensor
    images: torch.Tensor
    cams: torch.Tensor
    boxes: np.ndarray
    disk_backed: bool = False

    @staticmethod
    def array_bytes(n: int, K: int, height: int, width: int, image_itemsize: int = 4) -> int:
        """Bytes of the tri, bary and images arrays of n views: (K x 12 + 3 x itemsize)
        a pixel a view, 23.04 MB a view at 800x800 with K = 2 and float32 targets."""
        return n * height * width * (K * (4 + 8) + 3 * image_itemsize)

    @classmethod
    def build(cls, meshes, cameras, images, device, budget=None, folder=None) -> "ViewSet":
        """Cast every view's hits once, view by view, into arrays allocated once.

        Args:
            meshes: as :class:`HitCaster`; cameras: N cameras of one size; images (N, H, W,
                3) their targets (kept in their dtype).
            budget: bytes the arrays may hold in memory (:func:`view_budget`; default:
                :data:`VIEW_MEMORY_FRACTION` of the memory available on ``device``). When
                :meth:`array_bytes` exceeds it, they are disk-backed: ``.npy`` memory maps
                in ``folder`` (default the temporary directory), removed from the folder at
                once and freed with the arrays. Either way, the same values.
        Resident memory: all the arrays in memory (the images shared with ``images`` on
        CPU); disk-backed, 96 bytes a view (cams and boxes), the one view being cast, and
        what the page cache keeps of the files (clean pages the system reclaims).
        """
        dev = torch.device(device)
        caster = HitCaster(meshes)
        images = np.asarray(images)
        n, K = len(cameras), caster.K
        H, W = cameras[0].height, cameras[0].width
        if images.shape != (n, H, W, 3):
            raise ValueError(f"ViewSet: images of shape {images.shape}, expected {(n, H, W, 3)}")
        budget = view_budget(dev, budget)
        disk = cls.array_bytes(n, K, H, W, images.dtype.itemsize) > budget
        if disk:
            mm = disk_arrays(folder, {"tri": ((n, K, H, W), np.int32),
                                       "bary": ((n, K, H, W, 2), F32),
                                       "images": (images.shape, images.dtype)})
            tri, bary, imgs = (torch.from_numpy(mm[k]) for k in ("tri", "bary", "images"))
        else:
            tri = torch.empty((n, K, H, W), dtype=torch.int32, device=dev)
            bary = torch.empty((n, K, H, W, 2), dtype=torch.float32, device=dev)
            imgs = torch.as_tensor(np.ascontiguousarray(images), device=dev)
        boxes = np.empty((n, 4), np.int64)
        for i, camera in enumerate(cameras):
            hits = caster.cast_camera(camera)
            tri[i], bary[i] = torch.from_numpy(hits.tri), torch.from_numpy(hits.bary)
            boxes[i] = coverage_boxes(hits.tri[None])[0]
            if disk:
                imgs[i] = torch.from_numpy(np.ascontiguousarray(images[i]))
        cams = torch.as_tensor(np.stack([c.packed() for c in cameras]), device=dev)
        return cls(tri, bary, imgs, cams, boxes, disk)

    def __len__(self) -> int:
        return len(self.tri)

    @property
    def height(self) -> int:
        return self.tri.shape[2]

    @property
    def width(self) -> int:
        return self.tri.shape[3]

    @property
    def device(self) -> torch.device:
        """The device a step's tensors are on (the training's)."""
        return self.cams.device

    @property
    def resident_bytes(self) -> int:
        """Bytes the views hold in memory (host or device): all their arrays', or when
        disk-backed only cams' and boxes' (:data:`DISK_BACKED_VIEW_BYTES` a view)."""
        held = (self.cams,) if self.disk_backed else (self.tri, self.bary, self.images, self.cams)
        return sum(t.numel() * t.element_size() for t in held) + self.boxes.nbytes

    def window(self, i: int, y0: int, x0: int, ph: int, pw: int, halo: int):
        """:func:`crop` of view i with its ray directions: (tri, bary, dirs, inside), on
        :attr:`device` (disk-backed views of a GPU training: cropped on the host, then
        moved; the same integers and copies of the same floats)."""
        t, b, inside, rows, cols = crop(self.tri[i], self.bary[i], y0, x0, ph, pw, halo)
        if t.device != self.device:
            t, b, inside, rows, cols = (a.to(self.device) for a in (t, b, inside, rows, cols))
        return t, b, camera_dirs(self.cams[i], rows, cols), inside

    def target(self, i: int, y0: int, x0: int, ph: int, pw: int) -> torch.Tensor:
        """(ph, pw, 3) float32 target pixels of view i from (y0, x0), on :attr:`device`."""
        return self.images[i, y0:y0 + ph, x0:x0 + pw].to(self.device).float()

    def frame(self, shader: "NDRFShader", i: int, background: torch.Tensor) -> torch.Tensor:
        """The full (H, W, 3) frame of view i, shading only its coverage box: every pixel
        outside the box is a miss, so it shows ``background`` (no gradient), and the box's
        pixels equal a full-frame shading (the window carries the convs' halo). Same values
        and gradients as :func:`shade_image`, a fraction of its cost."""
        y0, x0, ph, pw = (int(v) for v in self.boxes[i])
        rgb = shader(*self.window(i, y0, x0, ph, pw, shader.config.kernel_size - 1),
                     background=background)
        if (ph, pw) == (self.height, self.width):
            return rgb
        out = background.to(rgb.dtype).expand(self.height, self.width, 3).clone()
        out[y0:y0 + ph, x0:x0 + pw] = rgb
        return out


# -- training -------------------------------------------------------------------------------
