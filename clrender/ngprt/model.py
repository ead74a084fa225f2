"""The NGP-RT model in PyTorch: auxiliary NGP for coarse features and attention, L explicit
fine hash levels, the six aggregation variants and the deferred MLP.

Everything a sample sees at training time is what the baked file gives the renderer
(docs/ngprt.md): coarse features are the auxiliary NGP evaluated at the 8 corners of the
``L_C`` cell and trilinearly interpolated, so baking the corner values loses nothing.

References: NGP-RT (Hu et al., ECCV 2024) §4.1-4.2, Eq. 5-8, S2.1.
"""
from __future__ import annotations

import math

import torch
from torch import nn

from .config import DEFERRED_HIDDEN, FEATURES, FUSION_HIDDEN, SH_DIM, ModelConfig
from . import torch_ops as ops
from .engine import TORCH, Engine
from .stages import mark, stage


class _TruncExp(torch.autograd.Function):
    """exp with the gradient clamped at exp(15), as Instant-NGP's density activation."""

    @staticmethod
    def forward(ctx, x):
        ctx.save_for_backward(x)
        return torch.exp(x)

    @staticmethod
    def backward(ctx, g):
        (x,) = ctx.saved_tensors
        return g * torch.exp(torch.clamp(x, max=15.0))


def trunc_exp(x: torch.Tensor) -> torch.Tensor:
    return _TruncExp.apply(x)


def _uniform(shape, bound):
    return nn.Parameter(torch.empty(shape).uniform_(-bound, bound))


def _linear(n_in, n_out):
    """(n_in, n_out) weight and (n_out,) bias in the baked layout (``x @ w + b``)."""
    bound = 1.0 / math.sqrt(n_in)
    return _uniform((n_in, n_out), math.sqrt(6.0 / n_in)), _uniform((n_out,), bound)


class AuxNGP(nn.Module):
    """Auxiliary multi-resolution hash encoding + one-hidden-layer MLP (S2.1).

    ``aux_levels`` levels from ``aux_min_res`` to ``L_C`` (geometric), ``aux_features``
    features each; a level whose dense grid fits the table is indexed densely. It is only
    evaluated at the corners of the L_C grid, which are vertices of the levels whose
    resolution is a multiple of L_C (the finest, L_C itself): those read one table row.
    """

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        n = cfg.aux_levels
        growth = (cfg.L_C / cfg.aux_min_res) ** (1.0 / max(n - 1, 1))
        self.resolutions = [int(round(cfg.aux_min_res * growth ** l)) for l in range(n)]
        self.T = 1 << cfg.aux_log2_T
        self.dense = [(R + 1) ** 3 <= self.T for R in self.resolutions]
        self.on_vertices = 0          # trailing levels with the L_C corners as vertices
        while self.on_vertices < n and self.resolutions[-1 - self.on_vertices] % cfg.L_C == 0:
            self.on_vertices += 1
        self.tables = _uniform((n, self.T, cfg.aux_features), 1e-4)
        self.w0, self.b0 = _linear(n * cfg.aux_features, cfg.aux_hidden)
        self.w1, self.b1 = _linear(cfg.aux_hidden, cfg.coarse_channels)

    def forward(self, u: torch.Tensor, engine: Engine = TORCH) -> torch.Tensor:
        """(N, 8 + n_attention) raw coarse channels at grid coordinates u (N, 3) of L_C-grid
        corners, computed by ``engine``."""
        return engine.aux_values(self.tables, u, self.resolutions, self.dense, self.on_vertices,
                                 self.w0, self.b0, self.w1, self.b1)


class NGPRT(nn.Module):
    """NGP-RT: coarse (auxiliary NGP at L_C corners) + attention-fused fine hash features,
    deferred shading. ``engine`` (:mod:`clrender.ngprt.engine`, chosen when the model is
    made, not saved with it) computes the grid lookups: the torch reference by default.

    Examples:
        >>> model = NGPRT(preset("tiny"))
        >>> fast = NGPRT(preset("tiny"), engine=engines.get("fast", torch.device("cpu")))
        >>> sigma, feat = model.sample(u)            # u: (N, 3) grid coordinates in [0, 1]
        >>> rgb = model.shade(acc, dirs)             # acc: (R, 7), dirs: (R, 3)
    """

    def __init__(self, cfg: ModelConfig, engine: Engine = TORCH):
        super().__init__()
        self.cfg = cfg
        self.engine = engine
        self.aux = AuxNGP(cfg)
        self.fine_tables = _uniform((cfg.L, cfg.T, FEATURES), 1e-4)
        if cfg.n_inv_attention:
            self.attention_inv = nn.Parameter(torch.zeros(cfg.n_inv_attention))
        if cfg.variant == "mlp":
            self.fusion_w0, self.fusion_b0 = _linear(FEATURES * cfg.L, FUSION_HIDDEN)
            self.fusion_w1, self.fusion_b1 = _linear(FUSION_HIDDEN, FEATURES)
            with torch.no_grad():  # start near `sum` so the fine levels are not drowned out
                self.fusion_w1.mul_(0.1)
        self.deferred_w0, self.deferred_b0 = _linear(3 + 4 + SH_DIM, DEFERRED_HIDDEN)
        self.deferred_w1, self.deferred_b1 = _linear(DEFERRED_HIDDEN, DEFERRED_HIDDEN)
        self.deferred_w2, self.deferred_b2 = _linear(DEFERRED_HIDDEN, 3)

    # -- coarse -----------------------------------------------------------------------
    def corner_values(self, corners: torch.Tensor) -> torch.Tensor:
        """(M, C) coarse channels at integer L_C-grid corners (M, 3) (what is baked)."""
        return self.aux(corners.to(torch.float32) / float(self.cfg.L_C), self.engine)

    def coarse(self, u: torch.Tensor, corner_grid: torch.Tensor | None = None) -> torch.Tensor:
        """(N, C) coarse channels at u: trilinear over the 8 corners of the L_C cell.

        Each unique corner of the batch is evaluated once; with ``corner_grid``
        ((L_C+1)^3, C), e.g. from :meth:`all_corner_values`, corners are read from it.
        """
        R = self.cfg.L_C
        if corner_grid is not None:                 # no gradient (the occupancy update)
            corners, w = ops.trilinear_corners(u * float(R), ops.cell_index(u, R))
            ids = (corners[..., 0] * (R + 1) + corners[..., 1]) * (R + 1) + corners[..., 2]
            return self.engine.corner_gather(corner_grid, ids, w)
        with stage("corners"):
            ucorn, idx, w = self.engine.coarse_corners(u, R)
        with stage("aux"):
            cv = mark(self.corner_values(ucorn), "aux")
        with stage("coarse"):
            return mark(self.engine.corner_gather(cv, idx, w), "coarse")

    @torch.no_grad()
    def all_corner_values(self, chunk: int = 1 << 16) -> torch.Tensor:
        """((L_C+1)^3, C) coarse channels at every corner of the L_C grid (no gradient)."""
        R1, dev = self.cfg.L_C + 1, self.fine_tables.device
        ids = torch.arange(R1 ** 3, device=dev)
        ijk = torch.stack([ids // (R1 * R1), (ids // R1) % R1, ids % R1], -1)
        return torch.cat([self.corner_values(ijk[i:i + chunk])
                          for i in range(0, len(ijk), chunk)])

    # -- fine -------------------------------------------------------------------------
    def fine(self, u: torch.Tensor) -> torch.Tensor:
        """(N, L, 8) fine features f^l at u, trilinear over hashed corners of R_l."""
        return self.engine.grid_lookup(self.fine_tables, u, self.cfg.fine_resolutions)

    def fuse(self, fine: torch.Tensor, coarse: torch.Tensor) -> torch.Tensor:
        """(N, 8) fused fine feature by ``variant`` (docs/ngprt.md "Fusion", Eq. 7-8)."""
        v, L = self.cfg.variant, self.cfg.L
        if v == "sum":
            return fine.sum(1)
        if v == "mlp":
            h = torch.relu(fine.reshape(len(fine), L * FEATURES) @ self.fusion_w0 + self.fusion_b0)
            return h @ self.fusion_w1 + self.fusion_b1
        if v.endswith("-v"):
            logits = coarse[:, FEATURES:]
        else:
            logits = self.attention_inv[None].expand(fine.shape[0], -1)
        a = torch.sigmoid(logits)
        if v.startswith("shared"):
            return (a[..., None] * fine).sum(1)
        omega, beta = a[:, 0::2], a[:, 1::2]                        # Eq. 7
        sigma = (omega * fine[..., 0]).sum(1, keepdim=True)          # Eq. 8
        colour = (beta[..., None] * fine[..., 1:]).sum(1)
        return torch.cat([sigma, colour], -1)

    def sample(self, u: torch.Tensor, corner_grid: torch.Tensor | None = None):
        """Density and colour features at grid coordinates u (N, 3).

        Returns:
            sigma: (N,) density per world unit (truncated exp).
            feat: (N, 7) diffuse rgb (3) + specular (4), pre-activation.
        """
        c = self.coarse(u, corner_grid)
        with stage("fine"):
            fine = mark(self.fine(u), "fine")
        with stage("fusion"):
            f = mark(c[:, :FEATURES] + self.fuse(fine, c), "fusion")  # Eq. 6
        return trunc_exp(f[:, 0]), f[:, 1:]

    # -- per pixel --------------------------------------------------------------------
    def shade(self, acc: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
        """(R, 3) colour in [0, 1] from accumulated features acc (R, 7) and unit view
        directions (R, 3) (Eq. 5, docs/ngprt.md "Per pixel")."""
        x = torch.cat([acc, ops.sh4(dirs)], -1)
        h = torch.relu(x @ self.deferred_w0 + self.deferred_b0)
        h = torch.relu(h @ self.deferred_w1 + self.deferred_b1)
        return torch.sigmoid(acc[:, :3] + h @ self.deferred_w2 + self.deferred_b2)


def render_rays(model: NGPRT, origins: torch.Tensor, dirs: torch.Tensor,
                occupancy: torch.Tensor, gamma: float, background: torch.Tensor,
                t_stop: float | None = None, step: float | None = None) -> dict:
    """Volume-render rays through ``model`` on the renderer's step lattice.

    Args:
        origins, dirs: (R, 3) float32 rays, unit directions.
        occupancy: (L_C, L_C, L_C) bool; lattice points in False cells are skipped.
        gamma: step scaler, ``s = gamma * s0`` (S2.3).
        background: (3,) float32 colour behind the model.
        t_stop: early ray termination on transmittance (``T_STOP`` at test time, None
            while training).
        step: the float32 lattice step itself, overriding ``gamma * s0`` (pass a baked
            model's ``step`` to march exactly its lattice).
    Returns:
        dict with ``rgb`` (R, 3), ``opacity`` (R,), ``depth`` (R,) world units along the
        ray, ``n_occ`` (R,) int64 samples, and the packed ``weights``, ``k``, ``ray_ids``,
        ``t`` (M,) of the samples; with ``t_stop``, ``n_occ`` counts the samples taken
        before the stop, as the renderer does.
    """
    cfg, n = model.cfg, len(origins)
    s = float(torch.tensor(gamma * cfg.s0 if step is None else step, dtype=torch.float32))
    with stage("rays"):
        ray_ids, k, t, delta, u = model.engine.lattice_samples(
            origins, dirs, occupancy, s, cfg.near, cfg.far, cfg.extent, cfg.scene == "unbounded")
    sigma, feat = model.sample(u)
    with stage("compositing"):
        w, T = ops.composite_weights(sigma, delta, ray_ids, n, t_stop, return_T=True)
        acc = mark(ops.accumulate(w[:, None] * feat, ray_ids, n), "compositing")
        opacity = mark(ops.accumulate(w, ray_ids, n), "compositing")
        depth = ops.accumulate(w * t, ray_ids, n)
        depth = torch.where(opacity > 0, depth / torch.clamp(opacity, min=1e-12),
                            torch.zeros_like(depth))
    with stage("shading"):
        rgb = model.shade(acc, dirs) * opacity[:, None] + background * (1.0 - opacity[:, None])
        rgb = mark(rgb, "shading")
    taken = ray_ids if t_stop is None else ray_ids[T >= t_stop]
    n_occ = torch.bincount(taken, minlength=n)
    return {"rgb": rgb, "opacity": opacity, "depth": depth, "n_occ": n_occ,
            "weights": w, "k": k, "ray_ids": ray_ids, "t": t, "delta": delta}


@torch.no_grad()
def render_image(model: NGPRT, camera, occupancy: torch.Tensor, gamma: float,
                 background=(1.0, 1.0, 1.0), chunk: int = 4096, step: float | None = None) -> dict:
    """Render a :class:`clrender.Camera` as the OpenCL renderer does (docs/ngprt.md):
    ``occupancy`` the baked ``occupancy_0``, early stop at ``T_STOP``; ``step`` as in
    :func:`render_rays`.

    Returns:
        dict of numpy arrays: ``rgb`` (H, W, 3), ``opacity``, ``depth`` (H, W) float32,
        ``n_occ`` (H, W) int32 (samples before the early stop).
    """
    from ..camera import generate_rays
    from .config import T_STOP

    dev = occupancy.device
    o, d = (torch.from_numpy(a.reshape(-1, 3).copy()).to(dev) for a in generate_rays(camera))
    bg = torch.as_tensor(background, dtype=torch.float32, device=dev)
    parts = {"rgb": [], "opacity": [], "depth": [], "n_occ": []}
    for i in range(0, len(o), chunk):
        out = render_rays(model, o[i:i + chunk], d[i:i + chunk], occupancy, gamma, bg, T_STOP,
                          step)
        for key in ("rgb", "opacity", "depth", "n_occ"):
            parts[key].append(out[key])
    H, W = camera.height, camera.width
    res = {k: torch.cat(v).cpu().numpy() for k, v in parts.items()}
    return {"rgb": res["rgb"].reshape(H, W, 3), "opacity": res["opacity"].reshape(H, W),
            "depth": res["depth"].reshape(H, W), "n_occ": res["n_occ"].reshape(H, W).astype("int32")}
