"""One table row's measurements, from :func:`bench.tables.measure.measure_row` through
:func:`bench.tables.seeds.aggregate` to :mod:`bench.tables.report`."""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np


@dataclass(frozen=True)
class RowResult:
    """A baked model measured on a dataset's test views (or the mean over seeds).

    Attributes:
        psnr, ssim: means over the test views (dB; 1 is identical).
        lpips: LPIPS-Alex v0.1 mean, None without its weights or on views under 31 px.
        time: the renderer's ms per frame, {median, p10, p90, min, n} (timed passes).
        wall_ms: median host time per frame (rgb only read back).
        stages: {stage: median ms} (``ms_<stage>`` of the renderer).
        stats: {table column: mean over pixels and views} of the method's ``SCALAR_STATS``.
        size_MB: the baked file's size.
        time_note: what the time covers (the renderer's ``TIME_NOTE``).
        time_at: {frame width: time summary} at the table's ``timing_sizes``.
        sample: the first test view's render, (H, W, 3) float32 in [0, 1].
        train_minutes, model_key: the model's training time and cache key.
        seeds, per_seed: over several seeds, the seeds and each seed's result (without its
            sample); None for one measurement.
        paired_speedup: against the row's baseline, timed as interleaved pairs at the test
            size (:func:`bench.tables.measure.time_pairs`): {ratio, lo, hi (95% interval), n,
            stage, size, ms_row, ms_baseline}; None without a baseline.
        paired_at: {"WxH": the same} at the table's ``paired_sizes``.
        paired_with: {row name: the same at the test size} against each row a comparison of
            the table sets this row against, other than its baseline.
        same_image: for a table whose rows must render their baseline's image
            (``same_image``): {identical, max_diff, views}; else None.
    """

    psnr: float
    ssim: float
    lpips: float | None
    time: dict
    wall_ms: float
    stages: dict
    stats: dict
    size_MB: float
    time_note: str
    time_at: dict = field(default_factory=dict)
    sample: np.ndarray | None = None
    train_minutes: float = 0.0
    model_key: str = ""
    seeds: list | None = None
    per_seed: list | None = None
    paired_speedup: dict | None = None
    paired_at: dict = field(default_factory=dict)
    paired_with: dict = field(default_factory=dict)
    same_image: dict | None = None

    def of_model(self, train_minutes: float, model_key: str) -> "RowResult":
        """This result with its model's training time and cache key."""
        return replace(self, train_minutes=float(train_minutes), model_key=model_key)

    def to_json(self) -> dict:
        """The JSON record of the measurement (no sample, no per-seed results)."""
        return {"PSNR": self.psnr, "SSIM": self.ssim, "LPIPS": self.lpips, "time": self.time,
                "wall_ms": self.wall_ms, "stages": self.stages, **self.stats,
                "time_at": {str(w): t for w, t in self.time_at.items()},
                "size_MB": self.size_MB, "time_note": self.time_note,
                "train_minutes": self.train_minutes, "model_key": self.model_key,
                "paired_speedup": self.paired_speedup, "paired_at": self.paired_at,
                "paired_with": self.paired_with,
                "same_image": self.same_image}
