"""NGP-RT model configuration and its presets.

One :class:`ModelConfig` fully describes a model's shape; the same names appear in
the paper (``L``, ``L_C``, ``s0``, ``G``), the baked file's manifest and the kernels'
``-D`` defines. Presets change sizes, never the algorithm.

References: NGP-RT (Hu et al., ECCV 2024) §4.1-4.3, S2.1, S2.3, S2.5.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, fields, replace

from .encoding import SH_C

VARIANTS = ("sum", "mlp", "shared-inv", "separate-inv", "shared-v", "separate-v")
SCENES = ("bounded", "unbounded")
# Training engines (clrender.ngprt.engine): the torch autograd specification, the fused C++ twin.
ENGINES = ("torch", "fast")
N_MIP = 5                 # occupancy mip levels R, R/2, ..., R/16, R = occ_res (S2.5)
T_STOP = 2e-3             # early ray termination threshold on transmittance (S2.5)
FEATURES = 8              # deferred feature: density 1, diffuse rgb 3, specular 4
SH_DIM = 16               # SH degree 4 view encoding (S2.1)
DEFERRED_HIDDEN = 64      # MLP_psi: 23 -> 64 -> 64 -> 3 (S2.1)
FUSION_HIDDEN = 64        # the `mlp` aggregation baseline: 8L -> 64 -> 8
INT32_MAX = 2**31 - 1     # the kernels index and count with int
# Most occupancy cells per axis (L_C and occ_res): the mip's ~1.14 occ_res^3 cells are
# indexed with int32.
MAX_L_C = 1024
# Most lattice points a ray may hold: the longest ray range over the step (S2.3), so a
# tiny gamma cannot make a march run (almost) forever or overflow the kernels' int k.
MAX_LATTICE_POINTS = 1 << 20
LOG2_T_RANGE = (4, 24)    # hash table sizes 2^4 .. 2^24, fine and auxiliary
# Breakpoints of an unbounded ray's lattice (docs/ngprt.md "Step lattice"): its start, the
# 12 candidate region changes of MERF's contraction, its end.
LATTICE_BREAKS = 14
# Farthest near/far (world units): keeps the unbounded lattice's per-piece terms
# (A = m^2 up to ~1e12, K * tau) far inside float32 (docs/ngprt.md "Step lattice").
MAX_FAR = 1e6
# Longest contracted arc length of an unbounded ray (S2.3, docs/ngprt.md "Step lattice"):
# a line crosses each of the contraction's 7 convex regions at most once, on one straight
# contracted segment: at most the diagonal 2*sqrt(3) of the unit cube plus 6 times the
# diagonal 3 of an outer region's image [1, 2] x [-1, 1]^2.
MAX_CONTRACTED_LENGTH = 2.0 * math.sqrt(3.0) + 6 * 3.0
# -D VARIANT codes of the kernels, VARIANT_SUM = 0 .. VARIANT_SEPARATE_V = 5.
VARIANT_CODES = {v: code for code, v in enumerate(VARIANTS)}


def kernel_constants() -> dict:
    """The constants the NGP-RT kernels share with this module, as ``-D`` defines.

    The kernels define none of them themselves (``kernels/ngprt_model.h`` refuses to
    build without them), so a change here reaches Python and OpenCL alike.

    Returns:
        ``{name: value}``: T_STOP, N_MIP, FEATURES, SH_DIM, DEFERRED_HIDDEN,
        FUSION_HIDDEN, LATTICE_BREAKS, the SH constants ``SH_C<i>`` (float32) and
        ``VARIANT_<NAME>`` (e.g. ``VARIANT_SEPARATE_V``) for each of
        :data:`VARIANTS` with its code from :data:`VARIANT_CODES`.
    """
    out = {"T_STOP": T_STOP, "N_MIP": N_MIP, "FEATURES": FEATURES, "SH_DIM": SH_DIM,
           "DEFERRED_HIDDEN": DEFERRED_HIDDEN, "FUSION_HIDDEN": FUSION_HIDDEN,
           "LATTICE_BREAKS": LATTICE_BREAKS}
    out.update({f"SH_C{i}": float(c) for i, c in enumerate(SH_C)})
    for variant, code in VARIANT_CODES.items():
        out["VARIANT_" + variant.upper().replace("-", "_")] = code
    return out


@dataclass(frozen=True)
class ModelConfig:
    """Shape of an NGP-RT model (everything but learned values).

    Attributes:
        L: number of fine hash levels; resolutions 2*L_C, 4*L_C, ... (S2.1).
        L_C: coarse grid resolution (voxels per axis).
        log2_T: fine hash tables hold T = 2**log2_T entries of 8 features.
        variant: feature aggregation, one of VARIANTS (Table 3).
        scene: "bounded" ([-1, 1]^3) or "unbounded" (MERF contraction into [-2, 2]^3).
        G_res: resolution of the occupancy distance grid G (paper: 256); divides occ_res.
        occupancy_res: the finest occupancy level's resolution, ``L_C * 2^j`` (j >= 0);
            None (the paper's ``L_C = 512``, and every trained model) ties it to L_C.
            Only a bake sets it (``grids="paper"``: :data:`PAPER_GRIDS`): the occupancy
            mip and G are rebuilt finer from the trained density, the model unchanged.
        coarse_block: voxels per side of a block of the sparse coarse grid.
        step_res: the lattice's base step is ``s0 = 2*sqrt(3)/step_res`` (S2.3); None
            (the paper) ties it to the coarse grid, ``step_res = L_C``.
        near, far: ray range in world units (far only bounds unbounded scenes).
        aux_levels, aux_min_res, aux_log2_T, aux_features, aux_hidden: the auxiliary
            NGP that yields coarse features and attention logits during training.

    Raises ``ValueError`` naming each bad field and its value: int fields must be
    integers in [1, 2^31 - 1], near/far finite with ``0 <= near < far <= MAX_FAR``, and
    the sizes must fit the grids and the kernels' int32 arithmetic (docs/ngprt.md
    "Baked file").
    """

    L: int = 2
    L_C: int = 512
    log2_T: int = 22
    variant: str = "separate-v"
    scene: str = "bounded"
    G_res: int = 256
    occupancy_res: int | None = None
    coarse_block: int = 8
    step_res: int | None = None
    near: float = 0.05
    far: float = 1000.0
    aux_levels: int = 6
    aux_min_res: int = 16
    aux_log2_T: int = 21
    aux_features: int = 4
    aux_hidden: int = 64

    def __post_init__(self):
        problems = _type_problems(self)
        if not problems:
            problems = _size_problems(self)
        if problems:
            raise ValueError("invalid ModelConfig: " + "; ".join(problems))

    @property
    def T(self) -> int:
        return 1 << self.log2_T

    @property
    def fine_resolutions(self) -> tuple[int, ...]:
        return tuple(self.L_C << (l + 1) for l in range(self.L))

    @property
    def occ_res(self) -> int:
        """Cells per axis of the finest occupancy level (``occupancy_res``, else L_C)."""
        return self.L_C if self.occupancy_res is None else self.occupancy_res

    @property
    def occ_shift(self) -> int:
        """log2(occ_res / L_C): an occupancy cell shifted right by it is its coarse cell."""
        return (self.occ_res // self.L_C).bit_length() - 1

    @property
    def extent(self) -> float:
        """Half-size E of the grid cube [-E, E]^3 in (contracted) scene space."""
        return 1.0 if self.scene == "bounded" else 2.0

    @property
    def s0(self) -> float:
        """Base lattice step 2*sqrt(3)/step_res, step_res = L_C unless set (S2.3:
        2*sqrt(3)/512 for L_C = 512, "inside our [-1, 1]^3 ROI grid"): world units in a
        bounded scene (at step_res = L_C a coarse voxel's diagonal); contracted units,
        uniformly, in an unbounded one (the same step as a bounded scene inside the unit
        cube, where the contraction is the identity)."""
        return 2.0 * math.sqrt(3.0) / (self.L_C if self.step_res is None else self.step_res)

    @property
    def max_ray_length(self) -> float:
        """Longest range of lattice distances a ray can have: the diagonal ``2*sqrt(3)``
        of the bounded [-1, 1]^3 box, or the longest contracted arc length of an
        unbounded ray, :data:`MAX_CONTRACTED_LENGTH` (~21.5). Over the step it bounds the
        lattice points of a ray."""
        return 2.0 * math.sqrt(3.0) if self.scene == "bounded" else MAX_CONTRACTED_LENGTH

    @property
    def min_gamma(self) -> float:
        """Smallest step scaler gamma that keeps a ray within MAX_LATTICE_POINTS points."""
        return self.max_ray_length / (MAX_LATTICE_POINTS * self.s0)

    @property
    def n_attention(self) -> int:
        """Attention logits stored per coarse corner: 2L (separate-v), L (shared-v), else 0."""
        return {"separate-v": 2 * self.L, "shared-v": self.L}.get(self.variant, 0)

    @property
    def n_inv_attention(self) -> int:
        """Spatially invariant attention logits: 2L (separate-inv), L (shared-inv), else 0."""
        return {"separate-inv": 2 * self.L, "shared-inv": self.L}.get(self.variant, 0)

    @property
    def coarse_channels(self) -> int:
        return FEATURES + self.n_attention

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict, where: str = "config") -> "ModelConfig":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"{where}: unknown model config keys {unknown}")
        return cls(**d)


_INT_FIELDS = ("L", "L_C", "log2_T", "G_res", "coarse_block", "aux_levels", "aux_min_res",
               "aux_log2_T", "aux_features", "aux_hidden")
_OPTIONAL_INT_FIELDS = ("step_res", "occupancy_res")    # None, or checked as the int fields


def _type_problems(c: ModelConfig) -> list[str]:
    """Fields of the wrong kind: ints that are not integers in [1, INT32_MAX], distances
    that are not finite numbers up to MAX_FAR, an unknown variant or scene (checked
    first: the sizes below do arithmetic on them)."""
    problems = []
    if c.variant not in VARIANTS:
        problems.append(f"variant {c.variant!r} is not one of {VARIANTS}")
    if c.scene not in SCENES:
        problems.append(f"scene {c.scene!r} is not one of {SCENES}")
    optional = tuple(n for n in _OPTIONAL_INT_FIELDS if getattr(c, n) is not None)
    for name in _INT_FIELDS + optional:
        v = getattr(c, name)
        if isinstance(v, bool) or not isinstance(v, numbers.Integral):
            problems.append(f"{name} must be an integer, got {v!r}")
        elif not 1 <= v <= INT32_MAX:
            problems.append(f"{name} must be in [1, {INT32_MAX}], got {v}")
    for name in ("near", "far"):
        v = getattr(c, name)
        if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
            problems.append(f"{name} must be a finite number, got {v!r}")
        elif v > MAX_FAR:
            problems.append(f"{name}={v} is above the maximum {MAX_FAR:g} (world units)")
    if not problems and not 0.0 <= c.near < c.far:
        problems.append(f"need 0 <= near < far, got near={c.near}, far={c.far}")
    return problems


def _size_problems(c: ModelConfig) -> list[str]:
    """Sizes the grids, the mip and the kernels' int32 arithmetic can hold."""
    problems = []
    lo, hi = LOG2_T_RANGE
    for name in ("log2_T", "aux_log2_T"):
        if not lo <= getattr(c, name) <= hi:
            problems.append(f"{name}={getattr(c, name)} out of range [{lo}, {hi}]")
    if c.L_C > MAX_L_C:
        problems.append(f"L_C={c.L_C} is above the maximum {MAX_L_C}")
    if c.L_C % (1 << (N_MIP - 1)) or c.L_C % c.coarse_block:
        problems.append(f"L_C={c.L_C} must be divisible by {1 << (N_MIP - 1)} "
                        f"and by coarse_block={c.coarse_block}")
    ratio = c.occ_res // c.L_C
    if c.occ_res > MAX_L_C:
        problems.append(f"occupancy_res={c.occ_res} is above the maximum {MAX_L_C}")
    if c.occ_res % c.L_C or ratio & (ratio - 1):
        problems.append(f"occupancy_res={c.occ_res} must be L_C={c.L_C} times a power of two")
    if c.occ_res % c.G_res:
        problems.append(f"G_res={c.G_res} must divide the occupancy resolution {c.occ_res}")
    if c.aux_min_res > c.L_C:
        problems.append(f"aux_min_res={c.aux_min_res} must be <= L_C={c.L_C} (the auxiliary "
                        f"grids grow from aux_min_res to L_C)")
    # Finest hash resolution L_C * 2^L; its corners (+1) and p = u * R must stay in int32.
    if c.L + 1 + int(c.L_C).bit_length() > 31:
        problems.append(f"L={c.L} is too large for L_C={c.L_C}: the fine grid resolutions "
                        f"L_C << (L+1) must fit in int32")
    return problems


# cpu: the paper tables, the main job and NDRF teachers, a model in minutes on 2 CPU cores
# (fast engine). The step is what a short run's quality turns on: L_C = 128 with
# step_res = 2 L_C gives s0 = 0.0135, fine enough for the built-in scene's fine texture
# and thin twigs, which a coarser step blurs. G_res = L_C / 2, as the paper's. Measured:
# docs/guides/training.md, "Presets".
_CPU = ModelConfig(L_C=128, step_res=256, log2_T=18, G_res=64, aux_levels=4, aux_log2_T=17)
PRESETS: dict[str, ModelConfig] = {
    # The paper's sizes (S2.1, S2.5).
    "paper": ModelConfig(L_C=512, log2_T=22, G_res=256, aux_log2_T=21),
    "cpu": _CPU,
    # cpu-long: real captures, about ten minutes of training on 2 CPU cores (fast engine).
    # The cpu model with 2^19-entry fine tables, chosen at equal minutes against the cpu
    # sizes and L_C = 256, whose costlier steps (a 256^3 occupancy update, twice the
    # samples a ray) fit fewer into the time (docs/results-training.md, "Presets at equal minutes").
    # Larger tables were not tried: gathers from tables beyond the last-level cache are
    # several times slower (docs/explanation/opencl.md, "PoCL facts the kernels rely on").
    "cpu-long": replace(_CPU, log2_T=19),
    # For tests: trains in well under a minute.
    "tiny": ModelConfig(L_C=32, log2_T=14, G_res=16, aux_levels=3, aux_log2_T=14),
}


# The paper's empty-space grids (S2.5): occupancy 512^3 .. 32^3, G 256^3, whatever L_C a
# model trained with (docs/ngprt.md "Grids").
PAPER_GRIDS = {"occupancy_res": PRESETS["paper"].L_C, "G_res": PRESETS["paper"].G_res}
GRIDS = ("preset", "paper")


def with_grids(config: ModelConfig, grids: str) -> ModelConfig:
    """``config`` with the empty-space grids ``grids``: ``preset`` (as trained) or
    ``paper`` (:data:`PAPER_GRIDS`; needs ``L_C`` to divide 512 by a power of two)."""
    if grids not in GRIDS:
        raise ValueError(f"grids {grids!r}: expected one of {', '.join(GRIDS)}")
    return config if grids == "preset" else replace(config, **PAPER_GRIDS)


def preset(name: str, **overrides) -> ModelConfig:
    """The model config of preset ``name`` with field ``overrides`` (e.g. L=3)."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; presets: {sorted(PRESETS)}")
    return replace(PRESETS[name], **overrides)
