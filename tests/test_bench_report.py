"""Ablation specs and the benchmark report writer (no training: measured values given)."""
import json
from dataclasses import replace

import numpy as np
import pytest

from bench.tables import ablation, compare, report, seeds, summary
from bench.tables.result import RowResult
from clrender import methods
from conftest import replace_bench


@pytest.mark.parametrize("key", ["table2", "table3", "table4"])
def test_tables_load(key):
    t = ablation.load_table(key)
    assert t.rows and t.scene == "builtin-bounded" and t.preset == "cpu"
    assert all(set(r.paper) <= set(t.paper_columns) for r in t.rows)


def test_table4_rows_are_the_marches_against_the_papers_without_G():
    t = ablation.load_table("table4")
    marches = [("paper", False, {}), ("paper", True, {}),
               ("paper", True, {"G_metric": "centre"}), ("ours", True, {})]
    assert [(r.model["L"], r.render["march"], r.render["use_G"], r.bake) for r in t.rows] == [
        (L, m, g, b) for L in (2, 3, 4) for m, g, b in marches]
    assert [r.baseline for r in t.rows] == [
        b for L in (2, 3, 4) for b in (None,) + (f"L={L} paper w/o G",) * 3]
    assert t.paired_stage == "march" and t.paired_sizes == ("1920x1080",) and t.same_image
    assert t.verdict_size == "1920x1080"
    assert [t.row_same_image(r) for r in t.rows] == [True, True, False, True] * 3
    assert all(not r.paper for r in t.rows if r.render["march"] == "ours")


@pytest.mark.parametrize("preset", methods.get("ndrf").presets)
def test_ndrf_table3_single_surface_is_the_full_models_outer_one(preset):
    """At every preset the single-surface row changes the surface count alone."""
    t = ablation.load_table("ndrf-table3")
    spec = {r.name: methods.bench_of("ndrf").model_spec(
        preset, **{k: v for k, v in r.model.items() if k != "teacher"}) for r in t.rows}
    full, single = spec["Full (duplex + conv + distill)"], spec["Single surface (outer)"]
    assert t.rows[-1].model == {"teacher": t.rows[0].model["teacher"]}   # the preset's own
    assert len(full["model"]["thresholds"]) == 2
    assert single["model"]["thresholds"] == full["model"]["thresholds"][:1]
    assert {**single, "model": {**single["model"], "thresholds": None}} == \
        {**full, "model": {**full["model"], "thresholds": None}}


@pytest.mark.parametrize("preset, same_as", [("cpu", "1e-2"), ("tiny", "1e-4")])
def test_ndrf_table3_single_surface_shares_the_thresholds_tables_models(tmp_path, preset,
                                                                       same_as):
    """The README quotes the thresholds table's row for Table 3's single surface: one model."""
    from bench.modelcache import cache

    single = ablation.load_table("ndrf-table3").rows[0]
    row = next(r for r in ablation.load_table("ndrf-thresholds").rows if r.name == same_as)
    keys = [cache.plan_model(tmp_path, tmp_path, "fp", preset, "ndrf", r.model).key
            for r in (single, row)]
    assert keys[0] == keys[1]


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
            "git_revision": "r", "date": "d", "argv": ["t"]}
    md = report.write_table(tmp_path, t, results, meta)
    line = next(l for l in md.splitlines() if l.startswith("| L=2 paper w/o G"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[1:3] == ["20.00", "25.67"]          # PSNR ours, paper
    assert cells[3:5] == ["40.0", "85.1"]            # Marching ours, paper
    data = json.loads((tmp_path / "table4.json").read_text())
    assert data["device"] == "dev" and len(data["rows"]) == 12
    assert (tmp_path / "table4.csv").read_text().count("\n") == 13
    assert (tmp_path / "table4.png").stat().st_size > 1000
    assert (tmp_path / "table4" / "l-2-paper-w-o-g.png").is_file()
    report.write_index(tmp_path)
    assert "table4/l-2-paper-w-g.png" in (tmp_path / "README.md").read_text()


def test_lpips_is_reported_beside_the_paper_or_as_not_measured(tmp_path):
    t = ablation.load_table("table2")
    results = [_measured(25.0, 5.0)] * 3
    md = report.write_table(tmp_path, t, results, META)
    row = next(l for l in md.splitlines() if l.startswith("| NGP-RT (L=2)"))
    assert "| n/a | 0.299 |" in row and "n/a without its weights" in md
    results = [_measured(25.0, 5.0, lpips=0.2)] * 3
    md = report.write_table(tmp_path, t, results, META)
    row = next(l for l in md.splitlines() if l.startswith("| NGP-RT (L=2)"))
    assert "| 0.200 | 0.299 |" in row and "LPIPS: AlexNet, linear heads v0.1" in md


def test_speedup_is_baseline_time_over_row_time(tmp_path):
    t = ablation.load_table("table4")
    # w/o G rows take 12 ms, w/ G rows 10 ms: the w/ G rows are 1.2x faster.
    results = [_measured(20.0, 12.0 if not r.render["use_G"] else 10.0) for r in t.rows]
    assert report.speedups(t, results) == [None, 1.2, 1.2, 1.2] * 3
    paper = report.speedups(t, results, key=lambda row, m: row.paper.get("Time (ms)"))
    assert paper[1] == pytest.approx(9.98 / 9.26)
    meta = {"device": "d", "preset": "cpu", "scene": "s", "resolution": "4x4",
            "git_revision": "r", "date": "d", "argv": ["t"]}
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
            "git_revision": "r", "date": "d", "argv": ["t"]}
    md = report.write_table(tmp_path, t, results, meta)
    head = next(l for l in md.splitlines() if l.startswith("| Row"))
    assert "Speed-up at 1920x1080" in head and "Image vs baseline" in head
    cells = lambda name: [c.strip() for c in next(
        l for l in md.splitlines() if l.startswith(f"| {name} |")).strip("|").split("|")]
    ours, paper_g = cells("L=2 ours"), cells("L=2 paper w/ G")
    assert "1.25x (1.10-1.40, 8 pairs)" in ours and "0.90x (0.80-1.05, 8 pairs)" in ours
    assert "identical" in ours and "differs (max 0.25)" in paper_g
    assert "geometric mean over interleaved pairs" in md and "bit for bit" in md
    data = json.loads((tmp_path / "table4.json").read_text())
    assert data["rows"][2]["paired_speedup"]["ratio"] == 1.25
    assert data["rows"][2]["paired_at"]["1920x1080"]["lo"] == 0.8
    # The claims: images compared instead of a PSNR verdict, the time judged on the pairs'
    # interval at the size the paper timed (the table's verdict_size, 1920x1080) against
    # the paper's 9.98 / 9.26 ms, the counts exactly (paper: marching 46.7 / 85.1,
    # occupied unchanged).
    claim = _cells(md, "L=2 paper w/ G − L=2 paper w/o G")
    assert claim[1] == "same image, bit for bit" and claim[5] == "IMAGES DIFFER"
    assert claim[6] == "0.90x (0.80-1.05, 8 pairs) at 1920x1080" and claim[8] == "within spread"
    assert claim[9] == ("Marching 0.500x (paper 0.549x): reproduces; "
                        "Occupied 1.000x (paper 1.000x): reproduces")
    claim = _cells(md, "L=2 ours − L=2 paper w/o G")      # ours: no paper figures to judge by
    assert claim[5] == "images identical" and claim[8:10] == ["", ""]
    slow = report.compare.speed_verdict({"ratio": 0.9, "lo": 0.8, "hi": 0.95}, 1.08)
    assert slow == "opposite"
    assert report.compare.speed_verdict({"ratio": 1.0, "lo": 0.9, "hi": 1.1}, 1.08) == \
        "within spread"


def _table(folder, name, columns='["PSNR"]', baseline="", model="{ variant = \"sum\", L = 2 }"):
    (folder / f"{name}.toml").write_text(
        'title = "t"\npaper_source = "p"\nscene = "builtin-bounded"\npreset = "cpu"\n'
        f'paper_columns = {columns}\n{baseline}\n[[rows]]\nname = "a"\nmodel = {model}\n')


def test_unknown_baseline_and_column_are_errors(tmp_path, monkeypatch):
    replace_bench(monkeypatch, "ngprt", ablations=tmp_path)
    _table(tmp_path, "bad", baseline='baseline = "nope"')
    with pytest.raises(ValueError, match="unknown baseline 'nope'"):
        ablation.load_table("bad")
    _table(tmp_path, "bad", columns='["PSNR", "Coverage"]')     # an NDRF statistic
    with pytest.raises(ValueError, match="column 'Coverage' is none of"):
        ablation.load_table("bad")
    _table(tmp_path, "bad", columns='["PSNR", "March (ms)", "Occupied"]')
    assert ablation.load_table("bad").paper_columns == ("PSNR", "March (ms)", "Occupied")


@pytest.mark.parametrize("compare, error", [
    ('[{ against = "nope" }]', "against 'nope' is not another row"),
    ('[{ against = "a" }]', "against 'a' is not another row"),
    ('[{ against = "b", claim = "better" }]', "claim 'better' is none of"),
    ('[{ against = "b", claim = "equivalent" }]', "a margin .dB. is for claim"),
    ('[{ against = "b", margin = 0.3 }]', "a margin .dB. is for claim"),
    ('[{ against = "b", claim = "equivalent", margin = -1 }]', "margin -1 must be a number"),
    ('[{ against = "b", within = 1 }]', "unknown keys .'within'."),
    ('"b"', "takes a list of tables"),
])
def test_bad_comparisons_are_errors_naming_the_file(tmp_path, monkeypatch, compare, error):
    replace_bench(monkeypatch, "ngprt", ablations=tmp_path)
    (tmp_path / "bad.toml").write_text(
        'title = "t"\npaper_source = "p"\nscene = "builtin-bounded"\npreset = "cpu"\n'
        'paper_columns = ["PSNR"]\nbaseline = "b"\n'
        f'[[rows]]\nname = "a"\nmodel = {{ L = 2 }}\ncompare = {compare}\n'
        '[[rows]]\nname = "b"\nmodel = { L = 3 }\n')
    with pytest.raises(ValueError, match=f"bad.toml: row 'a': compare.*{error}"):
        ablation.load_table("bad")


def test_declared_comparisons_replace_those_of_the_baseline(tmp_path, monkeypatch):
    replace_bench(monkeypatch, "ngprt", ablations=tmp_path)
    rows = "".join(f'[[rows]]\nname = "{n}"\nmodel = {{ L = 2 }}\n' for n in "abc")
    head = ('title = "t"\npaper_source = "p"\nscene = "builtin-bounded"\npreset = "cpu"\n'
            'paper_columns = ["PSNR"]\nbaseline = "a"\n')
    (tmp_path / "t.toml").write_text(head + rows)
    assert [(c.row, c.against) for c in ablation.load_table("t").comparisons] == \
        [("b", "a"), ("c", "a")]
    (tmp_path / "t.toml").write_text(head + rows + 'compare = [{ against = "b" }]\n')
    assert [(c.row, c.against) for c in ablation.load_table("t").comparisons] == [("c", "b")]


def test_tables_are_keyed_by_method_and_name(tmp_path, monkeypatch):
    """Two methods' `table4`: each asked for as method/name, their files apart."""
    replace_bench(monkeypatch, "ndrf", ablations=tmp_path)
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
            "git_revision": "r", "date": "d", "argv": ["t"]}
    md = report.write_table(tmp_path, t, [teacher, student], meta)
    row = next(l for l in md.splitlines() if l.startswith("| Student"))
    assert "| 2.00x |" in row
    assert "kernels; embree + kernels" in md
    data = json.loads((tmp_path / "ndrf-teacher.json").read_text())
    assert data["rows"][1]["Marching"] is None and data["rows"][1]["Coverage"] == 0.5


def _seeds(t, psnrs: dict) -> list[dict]:
    """Per row of ``t``: the aggregate of fake seeds 0, 1, ... with the given PSNRs."""
    n = len(next(iter(psnrs.values())))
    return [seeds.aggregate([_measured(p, 10.0 + i + s, lpips=0.2 + 0.01 * s,
                                       stages={"intersect": 1.0 + s})
                             for s, p in enumerate(psnrs[r.name])], list(range(n)))
            for i, r in enumerate(t.rows)]


def _cells(md: str, row: str) -> list[str]:
    line = next(l for l in md.splitlines() if l.startswith(f"| {row} |"))
    return [c.strip() for c in line.strip("|").split("|")]


META = {"device": "d", "preset": "cpu", "scene": "s", "resolution": "4x4", "git_revision": "r",
        "date": "d", "argv": ["t"]}


def test_seeds_give_mean_spread_and_the_claims_verdicts(tmp_path):
    t = ablation.load_table("table2")      # paper: L=3 +0.29 dB over L=2, L=4 +0.41 dB
    results = _seeds(t, {"NGP-RT (L=2)": [20.0, 20.2, 20.1],
                         "NGP-RT (L=3)": [21.0, 21.3, 21.1],    # +1.0, +1.1, +1.0
                         "NGP-RT (L=4)": [19.0, 19.3, 19.0]})   # -1.0, -0.9, -1.1
    md = report.write_table(tmp_path, t, results, META)
    head = _cells(md, "Row")
    assert head[11:13] == ["Speed-up", "Speed-up (paper)"] and "Verdict" not in head
    base, l3, l4 = (_cells(md, r.name) for r in t.rows)
    assert base[1:3] == ["20.10 ± 0.10", "25.64"] and base[5:7] == ["0.210 ± 0.010", "0.299"]
    assert base[7] == "11.0 ± 1.0" and l3[11:13] == ["0.92x", "0.74x"]     # 11 / 12 ms
    # mean 1.033, std 0.0577: 95% interval 1.033 ± 4.303 * 0.0577 / sqrt(3) = ± 0.143
    assert _cells(md, "NGP-RT (L=3) − NGP-RT (L=2)") == [
        "NGP-RT (L=3) − NGP-RT (L=2)", "difference", "+1.03 ± 0.06", "[+0.89, +1.18] (95%)",
        "+0.29", "reproduces", "0.92x", "0.74x", "", ""]
    assert _cells(md, "NGP-RT (L=4) − NGP-RT (L=2)")[2:6] == [
        "-1.00 ± 0.10", "[-1.25, -0.75] (95%)", "+0.41", "opposite"]
    assert "over 3 training seeds (0, 1, 2)" in md
    data = json.loads((tmp_path / "table2.json").read_text())
    row = data["rows"][1]
    assert row["seeds"] == [0, 1, 2] and [p["PSNR"] for p in row["per_seed"]] == [21.0, 21.3, 21.1]
    assert row["spread"]["PSNR"]["std"] == pytest.approx(np.std([21.0, 21.3, 21.1], ddof=1))
    claim = data["comparisons"][0]
    assert (claim["row"], claim["against"], claim["verdict"], claim["n"]) == \
        ("NGP-RT (L=3)", "NGP-RT (L=2)", "reproduces", 3)
    assert claim["lo"] == pytest.approx(1.0333 - 0.1434, abs=1e-3)
    csv_lines = (tmp_path / "table2.csv").read_text().splitlines()
    assert csv_lines[0].split(",")[4:8] == ["PSNR", "SSIM", "PSNR_std", "SSIM_std"]
    assert csv_lines[2].split(",")[4:8] == ["21.1333", "0.8000", "0.1528", "0.0000"]


def test_an_underpowered_claim_says_how_many_seeds_would_resolve_it():
    t = ablation.load_table("table2")
    results = _seeds(t, {"NGP-RT (L=2)": [20.0, 20.2], "NGP-RT (L=3)": [21.0, 21.4],
                         "NGP-RT (L=4)": [20.0, 20.2]})
    l3, l4 = compare.measure(t, results)
    # +1.0, +1.2 over 2 seeds: half-width 12.7 * 0.141 / sqrt(2) = 1.27 > 1.1 and > 0.29
    assert l3["verdict"] == "underpowered" and l3["seeds_needed"] == seeds.seeds_to_resolve(
        0.29, l3["std"]) == 4
    assert compare.verdict_cell(l3) == "underpowered (4 seeds would resolve it)"
    assert l4["std"] == 0.0 and l4["verdict"] == "within spread"   # no difference, no spread
    one = compare.measure(t, [_measured(20.0 + i, 10.0) for i in range(3)])
    assert [(c["mean"], c["std"], compare.verdict_cell(c)) for c in one] == \
        [(1.0, None, "one seed: no verdict"), (2.0, None, "one seed: no verdict")]


def test_table3_claims_are_the_papers():
    """Separate-Att (V) beats each light aggregation and is comparable to MLP (§5.2)."""
    t = ablation.load_table("table3")
    light = ["SUM", "Shared-Att (Inv)", "Separate-Att (Inv)", "Shared-Att (V)"]
    assert [(c.row, c.against, c.claim, c.margin) for c in t.comparisons] == \
        [("Separate-Att (V)", a, "difference", None) for a in light] \
        + [("Separate-Att (V)", "MLP", "equivalent", 0.3)]
    psnr = {"MLP": [26.0, 26.1, 26.2], "SUM": [25.0, 25.2, 25.1],
            "Shared-Att (Inv)": [26.0, 26.1, 26.4], "Separate-Att (Inv)": [25.5, 25.7, 25.6],
            "Shared-Att (V)": [26.2, 26.3, 26.4], "Separate-Att (V)": [25.95, 26.1, 26.15]}
    claims = compare.measure(t, _seeds(t, psnr))
    assert [round(c["paper"], 2) for c in claims] == [0.54, 0.36, 0.32, 0.16, -0.17]
    assert [c["verdict"] for c in claims] == ["reproduces", "within spread", "reproduces",
                                              "opposite", "equivalent"]
    mlp = claims[-1]                  # -0.05, 0.0, -0.05: 90% interval inside ±0.3
    assert mlp["confidence"] == 0.90 and -0.3 < mlp["lo"] < mlp["hi"] < 0.3
    assert mlp["speedup_paper"] == pytest.approx(68.02 / 16.17)
    assert mlp["speedup"] == {"ratio": pytest.approx(11.0 / 16.0)}   # MLP row 0, SepV row 5


def test_a_paired_speedup_interval_is_printed_where_a_result_carries_one(tmp_path):
    t = ablation.load_table("table3")
    results = [_measured(26.0, 10.0) for _ in t.rows]
    results[-1] = replace(results[-1], paired_speedup=_pair(4.05, 3.9, 4.2, 2.5, 10.1, "4x4")
                          | {"n": 20})
    md = report.write_table(tmp_path, t, results, META)
    assert "| 4.05x (3.90-4.20, 20 pairs) | 4.21x |" in next(
        l for l in md.splitlines() if l.startswith("| Separate-Att (V) |"))
    assert _cells(md, "Separate-Att (V) − MLP")[6] == "4.05x (3.90-4.20, 20 pairs)"
    assert _cells(md, "Separate-Att (V) − SUM")[6] == "1.00x"   # not the pairs' baseline


def test_index_lists_every_table_written_with_its_own_run(tmp_path):
    t3 = ablation.load_table("ndrf-table3")
    single = ablation.load_table("ndrf-thresholds")
    meta = {"device": "dev A", "preset": "cpu", "scene": "builtin-bounded", "resolution": "4x4",
            "git_revision": "r1", "date": "2026-01-01", "argv": ["t"]}
    measured = _measured(21.0, 20.0, stages={"intersect": 1.0})
    report.write_table(tmp_path, single, [measured] * len(single.rows), meta)
    report.write_index(tmp_path)
    text = (tmp_path / "README.md").read_text()
    assert "(ndrf-thresholds.md)" in text and "ndrf-table3" not in text
    report.write_table(tmp_path, t3, _seeds(t3, {r.name: [20.0, 21.0] for r in t3.rows}),
                       {**meta, "device": "dev B", "git_revision": "r2", "preset": "tiny",
                        "code": {"ndrf": "c0de"}})
    (tmp_path / "not-a-table.json").write_text("{}")
    report.write_index(tmp_path)
    text = (tmp_path / "README.md").read_text()
    first, second = text.index("## [NDRF Table 3"), text.index("## [NDRF supp. Table 2")
    assert first < second                              # ablation.list_tables() order
    assert ("2026-01-01, git r2, dev B, `tiny` preset, builtin-bounded scene, 2 seeds; trained "
            "by code ndrf c0de (bench/modelcache/fingerprint.py).") in text[first:second]
    assert "2026-01-01, git r1, dev A, `cpu` preset, builtin-bounded scene." in text[second:]
    assert "![Duplex (1e-4, 1e-2)](ndrf-thresholds/duplex-1e-4-1e-2.png)" in text
    assert "not-a-table" not in text


def test_the_summary_has_each_claim_and_is_copied_between_the_markers(tmp_path):
    t = ablation.load_table("table2")
    results = _seeds(t, {"NGP-RT (L=2)": [20.0, 20.2, 20.1], "NGP-RT (L=3)": [21.0, 21.3, 21.1],
                         "NGP-RT (L=4)": [19.0, 19.3, 19.0]})
    out = tmp_path / "results"
    report.write_table(out, t, results, META)
    report.write_index(out)
    index = (out / "README.md").read_text()
    assert index.index("## Summary") < index.index("### Table 2") < index.index("## Tables")
    assert ("| NGP-RT (L=3) − NGP-RT (L=2) | +1.03 ± 0.06 [+0.89, +1.18] | +0.29 | 0.92x | "
            "0.74x | reproduces |") in index
    assert "3 seeds, `cpu` preset, s scene, d, d, git r." in index
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\n## Results\nintro\n{summary.BEGIN}\nold\n{summary.END}\nafter\n")
    assert report.main(["--results", str(out), "--readme", str(readme)]) == 0
    text = readme.read_text()
    assert text.startswith("# x\n\n## Results\nintro\n") and text.endswith(f"{summary.END}\nafter\n")
    assert "old" not in text and summary.readme_summary(out).strip() in text
    assert ("| Table 2: fine-grained hash levels L, s scene | NGP-RT (L=3) − NGP-RT (L=2) | "
            "+1.03 ± 0.06 [+0.89, +1.18] | +0.29 | 0.92x | 0.74x | reproduces |") in text
    assert "git r" not in text and ", d," not in text                  # no dates, revisions
    assert summary.copy_into(readme, summary.readme_summary(out)) is False   # not written


def test_summary_errors_name_the_file(tmp_path, capsys):
    readme = tmp_path / "README.md"
    readme.write_text("no markers\n")
    with pytest.raises(ValueError, match="README.md: expected one <!-- results:begin -->"):
        summary.copy_into(readme, "x")
    (tmp_path / "table2.json").write_text(json.dumps({"title": "t", "rows": [{}]}))
    with pytest.raises(ValueError, match="table2.json: not a table written by bench.run"):
        summary.summary(tmp_path)
    assert report.main(["--results", str(tmp_path / "none")]) == 2
    assert "none: no such folder" in capsys.readouterr().err
    assert summary.summary(tmp_path / "none").startswith("No table has been run into")


def test_the_projects_readme_takes_the_summary(tmp_path):
    from pathlib import Path

    readme = tmp_path / "README.md"
    original = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    readme.write_text(original)
    assert summary.copy_into(readme, "generated") is True
    text = readme.read_text()
    assert f"{summary.BEGIN}\ngenerated\n{summary.END}" in text
    assert text.split(summary.BEGIN)[0] == original.split(summary.BEGIN)[0]
    assert text.split(summary.END)[1] == original.split(summary.END)[1]


@pytest.mark.parametrize("ours, paper, verdict", [
    (0.55, 0.55, "reproduces"), (0.77, 0.55, "reproduces"), (0.80, 0.55, "direction only"),
    (0.99, 0.55, "direction only"), (1.0, 0.55, "opposite"), (1.16, 0.55, "opposite"),
    (1.0, 1.0, "reproduces"), (0.98, 1.0, "differs"), (1.6, 1.3, "reproduces")])
def test_count_verdict_judges_size_as_well_as_direction(ours, paper, verdict):
    # The rule fixed before the runs: at least half the paper's relative change, its way.
    from bench.tables.compare import COUNT_SHARE, count_verdict

    assert COUNT_SHARE == 0.5
    assert count_verdict(ours, paper) == verdict
