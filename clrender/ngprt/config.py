"""NGP-RT model configuration and its presets.

One :class:`ModelConfig` fully describes a model's shape; the same names appear in
the paper (``L``, ``L_C``, ``s0``, ``G``), the baked file's manifest and the kernels'
``-D`` defines. Presets change sizes, never the algorithm.

References: NGP-RT (Hu et al., ECCV 2024) §4.1-4.3, S2.1, S2.3, S2.5.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

VARIANTS = ("sum", "mlp", "shared-inv", "separate-inv", "shared-v", "separate-v")
SCENES = ("bounded", "unbounded")
N_MIP = 5                 # occupancy mip levels L_C, L_C/2, ..., L_C/16 (S2.5)
T_STOP = 2e-3             # early ray termination threshold on transmittance (S2.5)
FEATURES = 8              # deferred feature: density 1, diffuse rgb 3, specular 4
SH_DIM = 16               # SH degree 4 view encoding (S2.1)
DEFERRED_HIDDEN = 64      # MLP_psi: 23 -> 64 -> 64 -> 3 (S2.1)
FUSION_HIDDEN = 64        # the `mlp` aggregation baseline: 8L -> 64 -> 8


@dataclass(frozen=True)
class ModelConfig:
    """Shape of an NGP-RT model (everything but learned values).

    Attributes:
        L: number of fine hash levels; resolutions 2*L_C, 4*L_C, ... (S2.1).
        L_C: coarse grid resolution (voxels per axis), also the finest occupancy level.
        log2_T: fine hash tables hold T = 2**log2_T entries of 8 features.
        variant: feature aggregation, one of VARIANTS (Table 3).
        scene: "bounded" ([-1, 1]^3) or "unbounded" (MERF contraction into [-2, 2]^3).
        G_res: resolution of the occupancy distance grid G (paper: 256 for L_C = 512).
        coarse_block: voxels per side of a block of the sparse coarse grid.
        near, far: ray range in world units (far only bounds unbounded scenes).
        aux_levels, aux_min_res, aux_log2_T, aux_features, aux_hidden: the auxiliary
            NGP that yields coarse features and attention logits during training.
    """

    L: int = 2
    L_C: int = 512
    log2_T: int = 22
    variant: str = "separate-v"
    scene: str = "bounded"
    G_res: int = 256
    coarse_block: int = 8
    near: float = 0.05
    far: float = 1000.0
    aux_levels: int = 6
    aux_min_res: int = 16
    aux_log2_T: int = 21
    aux_features: int = 4
    aux_hidden: int = 64

    def __post_init__(self):
        problems = []
        if self.variant not in VARIANTS:
            problems.append(f"variant {self.variant!r} is not one of {VARIANTS}")
        if self.scene not in SCENES:
            problems.append(f"scene {self.scene!r} is not one of {SCENES}")
        if self.L < 1:
            problems.append(f"L must be >= 1, got {self.L}")
        if self.L_C % (1 << (N_MIP - 1)) or self.L_C % self.coarse_block:
            problems.append(f"L_C={self.L_C} must be divisible by {1 << (N_MIP - 1)} "
                            f"and by coarse_block={self.coarse_block}")
        if self.G_res < 1 or self.L_C % self.G_res:
            problems.append(f"G_res={self.G_res} must divide L_C={self.L_C}")
        if not 4 <= self.log2_T <= 24:
            problems.append(f"log2_T={self.log2_T} out of range [4, 24]")
        if not 0.0 <= self.near < self.far:
            problems.append(f"need 0 <= near < far, got near={self.near}, far={self.far}")
        if problems:
            raise ValueError("invalid ModelConfig: " + "; ".join(problems))

    @property
    def T(self) -> int:
        return 1 << self.log2_T

    @property
    def fine_resolutions(self) -> tuple[int, ...]:
        return tuple(self.L_C << (l + 1) for l in range(self.L))

    @property
    def extent(self) -> float:
        """Half-size E of the grid cube [-E, E]^3 in (contracted) scene space."""
        return 1.0 if self.scene == "bounded" else 2.0

    @property
    def s0(self) -> float:
        """Base lattice step: the diagonal of a coarse voxel, 2*sqrt(3)/L_C in the
        bounded [-1, 1]^3 cube (S2.3: 2*sqrt(3)/512 for L_C = 512)."""
        return 2.0 * math.sqrt(3.0) / self.L_C

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


PRESETS: dict[str, ModelConfig] = {
    # The paper's sizes (S2.1, S2.5).
    "paper": ModelConfig(L_C=512, log2_T=22, G_res=256, aux_log2_T=21),
    # Trains the built-in bounded scene on 2 CPU cores in about 10 minutes.
    "cpu": ModelConfig(L_C=64, log2_T=18, G_res=32, aux_levels=4, aux_log2_T=17),
    # For tests: trains in well under a minute.
    "tiny": ModelConfig(L_C=32, log2_T=14, G_res=16, aux_levels=3, aux_log2_T=14),
}


def preset(name: str, **overrides) -> ModelConfig:
    """The model config of preset ``name`` with field ``overrides`` (e.g. L=3)."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; presets: {sorted(PRESETS)}")
    return replace(PRESETS[name], **overrides)
