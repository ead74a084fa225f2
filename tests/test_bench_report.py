"""Ablation specs and the benchmark report writer (no training: measured values given)."""
import json
from dataclasses import replace

import numpy as np
import pytest

from bench import ablation, report, seeds
from bench.result import RowResult
from clrender import methods


@pytest.mark.parametrize("key", ["table2", "table3", "table4"])
def test_tables_load(key):
    t = ablation.load_table(key)
    assert t.rows and t.scene == "builtin-bounded" and t.preset == "cpu"
    assert all(set(r.paper) <= set(t.paper_columns) for r in t.rows)


def test_table4_rows_are_the_three_marches_against_the_papers_without_G():
    t = ablation.load_table("table4")
    marches = [("paper", False), ("paper", True), ("ours", True)]
    assert [(r.model["L"], r.render["march"], r.render["use_G"]) for r in t.rows] == [
        (L, m, g) for L in (2, 3, 4) for m, g in marches]
    assert [r.baseline for r in t.rows] == [
        b for L in (2, 3, 4) for b in (None, f"L={L} paper w/o G", f"L={L} paper w/o G")]
    assert t.paired_stage == "march" and t.paired_sizes == ("1920x1080",) and t.same_image
    assert all(not r.paper for r in t.rows if r.render["march"] == "ours")


def test_unknown_table_lists_the_known_ones():
    with pytest.raises(ValueError, match="table4"):
        ablation.load_table("table9")


def _time(ms):
    return {"median": ms, "p10": ms - 1, "p90": ms + 1, "min": ms - 1, "n": 10}


def _measured(psnr, ms, **fields):
    m = RowResult(psnr=psnr, ssim=0.8, lpips=None, time=_time(ms), wall_ms=ms + 2, stages={},
                  stats={"Marching": 40.0, "Occupied": 12.5}, size_MB=3.0,
                  time_note="time per frame", sample=np.full((4, 4, 3), 0.5, np.float32),
                  train_minutes=1.5, model_key="abc")
    return replace(m, **fields)


def test_write_table_puts_paper_figures_beside_ours(tmp_path):
    t = ablation.load_table("table4")
    results = [_measured(20.0 + i, 10.0 + i) for i in range(len(t.rows))]
    meta = {"device": "dev", "preset": "cpu", "scene": "builtin-bounded", "resolution": "4x4",
            "git_revision": "r", "date": "d"}
    md = report.write_table(tmp_path, t, results, meta)
    line = next(l for l in md.splitlines() if l.startswith("| L=2 paper w/o G"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[1:3] == ["20.00", "25.67"]          # PSNR ours, paper
    assert cells[3:5] == ["40.0", "85.1"]            # Marching ours, paper
    data = json.loads((tmp_path / "table4.json").read_text())
    assert data["device"] == "dev" and len(data["rows"]) == 9
    assert (tmp_path / "table4.csv").read_text().count("\n") == 10
    assert (tmp_path / "table4.png").stat().st_size > 1000
    assert (tmp_path / "table4" / "l-2-paper-w-o-g.png").is_file()
    report.write_index(tmp_path)
    assert "table4/l-2-paper-w-g.png" in (tmp_path / "README.md").read_text()


def test_lpips_is_reported_beside_the_paper_or_as_not_measured(tmp_path):
    t = ablation.load_table("table2")
    meta = {"device": "d", "preset": "cpu", "scene": "s", "resolution": "4x4"}
    results = [_measured(25.0, 5.0)] * 3
    md = report.markdown(t, results, meta, report.effects(t, results))
    row = next(l for l in md.splitlines() if l.startswith("| NGP-RT (L=2)"))
    assert "| n/a | 0.299 |" in row and "LPIPS: n/a where its weights" in md
    results = [_measured(25.0, 5.0, lpips=0.2)] * 3
    md = report.markdown(t, results, meta, report.effects(t, results))
    row = next(l for l in md.splitlines() if l.startswith("| NGP-RT (L=2)"))
    assert "| 0.200 | 0.299 |" in row and "LPIPS: AlexNet, linear heads v0.1" in md


def test_speedup_is_baseline_time_over_row_time(tmp_path):
    t = ablation.load_table("table4")
    # w/o G rows take 12 ms, w/ G rows 10 ms: the w/ G rows are 1.2x faster.
    results = [_measured(20.0, 12.0 if not r.render["use_G"] else 10.0) for r in t.rows]
    assert report.speedups(t, results) == [None, 1.2, 1.2] * 3
    paper = report.speedups(t, results, key=lambda row, m: row.paper.get("Time (ms)"))
    assert paper[1] == pytest.approx(9.98 / 9.26)
    meta = {"device": "d", "preset": "cpu", "scene": "s", "resolution": "4x4",
            "git_revision": "r", "date": "d"}
    md = report.write_table(tmp_path, t, results, meta)
    row = next(l for l in md.splitlines() if l.startswith("| L=3 paper w/ G"))
    assert "| 1.20x | 1.11x |" in row
    data = json.loads((tmp_path / "table4.json").read_text())
    assert data["rows"][1]["baseline"] == "L=2 paper w/o G" and data["rows"][1]["speedup"] == 1.2


def _pair(ratio, lo, hi, ms_row, ms_baseline, size):
    return {"ratio": ratio, "lo": lo, "hi": hi, "n": 8, "stage": "march", "size": size,
            "ms_row": ms_row, "ms_baseline": ms_baseline}


def test_paired_speedup_counts_and_images_are_printed(tmp_path):
    t = ablation.load_table("table4")
    results = []
    for r in t.rows:
        m = _measured(20.0, 12.0)
        if r.baseline:
            identical = r.render["march"] == "ours"
            m = replace(m, stats={"Marching": 20.0, "Occupied": 12.5},
                        paired_speedup=_pair(1.25, 1.1, 1.4, 4.0, 5.0, "4x4"),
                        paired_at={"1920x1080": _pair(0.9, 0.8, 1.05, 90.0, 81.0, "1920x1080")},
                        same_image={"identical": identical, "max_diff": 0.0 if identical
                                    else 0.25, "views": 2})
        results.append(m)
    meta = {"device": "d", "preset": "cpu", "scene": "s", "resolution": "4x4",
            "git_revision": "r", "date": "d"}
    md = report.write_table(tmp_path, t, results, meta)
    head = next(l for l in md.splitlines() if l.startswith("| Row"))
    assert "march ms, test size (paired)" in head and "Speed-up at 1920x1080" in head
    cells = lambda name: [c.strip() for c in next(
        l for l in md.splitlines() if l.startswith(f"| {name} |")).strip("|").split("|")]
    ours, paper_g, base = cells("L=2 ours"), cells("L=2 paper w/ G"), cells("L=2 paper w/o G")
    assert "1.25x (1.10-1.40)" in ours and "0.90x (0.80-1.05)" in ours
    assert "4.00" in ours and "90.00" in ours and "identical" in ours
    assert "Marching 0.500x, Occupied 1.000x" in ours
    assert "**DIFFERS** (max 0.25)" in paper_g
    assert "5.00" in base and "81.00" in base               # the baseline's time, from its pairs
    assert "interleaved pairs" in md and "bit for bit" in md
    data = json.loads((tmp_path / "table4.json").read_text())
    assert data["rows"][2]["paired_speedup"]["ratio"] == 1.25
    assert data["rows"][2]["paired_at"]["1920x1080"]["lo"] == 0.8


def _table(folder, name, columns='["PSNR"]', baseline="", model="{ variant = \"sum\", L = 2 }"):
    (folder / f"{name}.toml").write_text(
        'title = "t"\npaper_source = "p"\nscene = "builtin-bounded"\npreset = "cpu"\n'
        f'paper_columns = {columns}\n{baseline}\n[[rows]]\nname = "a"\nmodel = {model}\n')


def test_unknown_baseline_and_column_are_errors(tmp_path, monkeypatch):
    monkeypatch.setattr(methods.get("ngprt"), "ABLATIONS", tmp_path)
    _table(tmp_path, "bad", baseline='baseline = "nope"')
    with pytest.raises(ValueError, match="unknown baseline 'nope'"):
        ablation.load_table("bad")
    _table(tmp_path, "bad", columns='["PSNR", "Coverage"]')     # an NDRF statistic
    with pytest.raises(ValueError, match="column 'Coverage' is none of"):
        ablation.load_table("bad")
    _table(tmp_path, "bad", columns='["PSNR", "March (ms)", "Occupied"]')
    assert ablation.load_table("bad").paper_columns == ("PSNR", "March (ms)", "Occupied")


def test_tables_are_keyed_by_method_and_name(tmp_path, monkeypatch):
    """Two methods' `table4`: each asked for as method/name, their files apart."""
    monkeypatch.setattr(methods.get("ndrf"), "ABLATIONS", tmp_path)
    _table(tmp_path, "table4", model="{ kernel_size = 1, teacher = { L = 2 } }")
    keys = ablation.list_tables()
    assert "ndrf/table4" in keys and "ngprt/table4" in keys and "table4" not in keys
    assert "table2" in keys and "ndrf-table3" not in keys      # the folder replaced
    with pytest.raises(ValueError, match="unknown table 'table4'"):
        ablation.load_table("table4")
    t = ablation.load_table("ndrf/table4")
    assert (t.method, t.stem, t.rows[0].model["kernel_size"]) == ("ndrf", "ndrf-table4", 1)
    assert ablation.load_table("ngprt/table2").key == "table2"


def test_a_table_may_mix_methods(tmp_path):
    """ndrf-teacher: an NGP-RT row (marching statistics) beside an NDRF row (coverage)."""
    t = ablation.load_table("ndrf-teacher")
    assert [r.method for r in t.rows] == ["ngprt", "ndrf"] and t.timing_sizes == (800,)
    teacher = _measured(23.0, 40.0, time_note="kernels", time_at={800: _time(600.0)},
                        stages={"march": 30.0, "deferred": 10.0})
    student = _measured(21.0, 20.0, stats={"Coverage": 0.5}, time_note="embree + kernels",
                        time_at={800: _time(300.0)},
                        stages={"intersect": 12.0, "gather": 3.0, "conv0": 4.0, "conv1": 1.0})
    meta = {"device": "d", "preset": "cpu", "scene": "s", "resolution": "4x4",
            "git_revision": "r", "date": "d"}
    md = report.write_table(tmp_path, t, [teacher, student], meta)
    row = next(l for l in md.splitlines() if l.startswith("| Student"))
    assert "| 2.00x |" in row and "| 300.0 |" in row and "intersect 12.0" in row
    assert "kernels; embree + kernels" in md
    data = json.loads((tmp_path / "ndrf-teacher.json").read_text())
    assert data["rows"][1]["Marching"] is None and data["rows"][1]["Coverage"] == 0.5


def _two_seeds(t, psnrs: dict) -> list[dict]:
    """Per row of ``t``: the aggregate of two fake seeds with the given PSNRs."""
    return [seeds.aggregate([_measured(p, 10.0 + i + s, lpips=0.2 + 0.01 * s,
                                       stages={"intersect": 1.0 + s})
                             for s, p in enumerate(psnrs[r.name])], [0, 1])
            for i, r in enumerate(t.rows)]


def _cells(md: str, row: str) -> list[str]:
    line = next(l for l in md.splitlines() if l.startswith(f"| {row} |"))
    return [c.strip() for c in line.strip("|").split("|")]


def test_two_seeds_give_mean_spread_and_a_verdict(tmp_path):
    t = ablation.load_table("table2")      # paper: L=3 +0.29 dB over L=2, L=4 +0.41 dB
    results = _two_seeds(t, {"NGP-RT (L=2)": [20.0, 20.2],
                             "NGP-RT (L=3)": [21.0, 21.4],    # +1.0, +1.2: beyond 0.2
                             "NGP-RT (L=4)": [19.0, 19.4]})   # -1.0, -0.8: beyond 0.2
    meta = {"device": "d", "preset": "cpu", "scene": "s", "resolution": "4x4",
            "git_revision": "r", "date": "d"}
    md = report.write_table(tmp_path, t, results, meta)
    head = _cells(md, "Row")
    assert head[11:16] == ["Speed-up", "Speed-up (paper)", "ΔPSNR vs baseline", "ΔPSNR (paper)",
                           "Verdict"]
    base, l3, l4 = (_cells(md, r.name) for r in t.rows)
    assert base[1:3] == ["20.10 ± 0.14", "25.64"] and base[5:7] == ["0.205 ± 0.007", "0.299"]
    assert base[7] == "10.5 ± 0.7" and base[13:16] == ["", "", ""]
    assert l3[13:16] == ["+1.10 ± 0.14", "+0.29", "reproduces"]
    assert l4[13:16] == ["-0.90 ± 0.14", "+0.41", "opposite"]
    assert "over 2 training seeds (0, 1)" in md and "|mean Δ| > 2 × std(Δ) / √N" in md
    data = json.loads((tmp_path / "table2.json").read_text())
    row = data["rows"][1]
    assert row["seeds"] == [0, 1] and [p["PSNR"] for p in row["per_seed"]] == [21.0, 21.4]
    assert row["spread"]["PSNR"] == {"std": pytest.approx(0.4 / 2 ** 0.5), "min": 21.0,
                                     "max": 21.4}
    assert row["delta_PSNR"]["verdict"] == "reproduces" and data["rows"][0]["delta_PSNR"] is None
    csv_lines = (tmp_path / "table2.csv").read_text().splitlines()
    assert csv_lines[0].split(",")[4:8] == ["PSNR", "SSIM", "PSNR_std", "SSIM_std"]
    assert csv_lines[2].split(",")[4:8] == ["21.2000", "0.8000", "0.2828", "0.0000"]


def test_index_lists_every_table_written_with_its_own_run(tmp_path):
    t3 = ablation.load_table("ndrf-table3")
    single = ablation.load_table("ndrf-thresholds")
    meta = {"device": "dev A", "preset": "cpu", "scene": "builtin-bounded", "resolution": "4x4",
            "git_revision": "r1", "date": "2026-01-01"}
    measured = _measured(21.0, 20.0, stages={"intersect": 1.0})
    report.write_table(tmp_path, single, [measured] * len(single.rows), meta)
    report.write_index(tmp_path)
    text = (tmp_path / "README.md").read_text()
    assert "(ndrf-thresholds.md)" in text and "ndrf-table3" not in text
    report.write_table(tmp_path, t3, _two_seeds(t3, {r.name: [20.0, 21.0] for r in t3.rows}),
                       {**meta, "device": "dev B", "git_revision": "r2", "preset": "tiny"})
    (tmp_path / "not-a-table.json").write_text("{}")
    report.write_index(tmp_path)
    text = (tmp_path / "README.md").read_text()
    first, second = text.index("## [NDRF Table 3"), text.index("## [NDRF supp. Table 2")
    assert first < second                              # ablation.list_tables() order
    assert "2026-01-01, git r2, dev B, `tiny` preset, builtin-bounded scene, 2 seeds." \
        in text[first:second]
    assert "2026-01-01, git r1, dev A, `cpu` preset, builtin-bounded scene." in text[second:]
    assert "![Duplex (1e-4, 1e-2)](ndrf-thresholds/duplex-1e-4-1e-2.png)" in text
    assert "not-a-table" not in text
