"""docs/results.md's generated blocks and the README's verdict tables against the committed
runs (docs/results/*.json): regenerated, they are the committed text, byte for byte; each
block shows the command that made its run, with its paths as a user types them."""
import json
import os
import shutil
from pathlib import Path

import pytest

from bench.tables import command, markdown, page, report, summary
from test_machine_paths import machine_paths

ROOT = Path(__file__).resolve().parents[1]
RUNS, DOCS, README = ROOT / "docs" / "results", ROOT / "docs" / "results.md", ROOT / "README.md"


@pytest.fixture
def tree(tmp_path):
    """Copies of the committed runs, results page and README under ``tmp_path``; returns
    the arguments of ``bench.tables.report`` for them."""
    shutil.copytree(RUNS, tmp_path / "runs")
    for f in (DOCS, README):
        shutil.copy(f, tmp_path / f.name)
    return ["--from", str(tmp_path / "runs"), "--docs", str(tmp_path / "results.md"),
            "--readme", str(tmp_path / "README.md")]


def _edit_run(folder: Path, name: str, edit) -> None:
    path = folder / f"{name}.json"
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))


def test_the_committed_page_and_readme_are_their_runs_regenerated(tree, tmp_path, capsys):
    assert report.main(tree) == 0
    out = capsys.readouterr().out
    assert "README.md: summary unchanged" in out and "results.md: blocks unchanged" in out
    assert (tmp_path / "results.md").read_text() == DOCS.read_text()
    assert (tmp_path / "README.md").read_text() == README.read_text()
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == \
        sorted(p.name for p in RUNS.iterdir())                        # no index written there


def test_every_committed_run_has_its_block_with_its_command_and_the_readme_no_date():
    runs = page.load(RUNS)
    assert "table4" in runs and "table4-grids-paper" in runs
    text, readme = DOCS.read_text(), README.read_text()
    for name, data in runs.items():
        block = text[text.index(page.begin(name)):text.index(page.end(name))]
        assert f"{data['date']}, git {data['git_revision']}" in block
        assert f"**{markdown.title(data)}**" in block
        assert "```bash\n" + "\n".join(command.lines(data)) + "\n```" in block
        assert command.lines(data)[-1].startswith("python -m bench.run ")
        assert machine_paths(block) == [] and machine_paths(json.dumps(data)) == []
        if command.is_dirty(data):
            assert "(**uncommitted changes**" in block
    generated = readme[readme.index(summary.BEGIN):readme.index(summary.END)]
    assert markdown.title(runs["table4"]) in generated
    assert runs["table4"]["date"] not in readme and runs["table4"]["git_revision"] not in readme


def test_the_main_job_and_each_bake_option_are_named_as_their_command_names_them():
    """``python -m bench.run table4`` writes table4.json; ``--bake grids=paper``
    table4-grids-paper.json; a public scene's block assembles its folder first."""
    runs = page.load(RUNS)
    assert command.lines(runs["table4"]) == ["python -m bench.run table4"]
    assert runs["table4"]["table"] == "table4"
    paper = runs["table4-grids-paper"]
    assert (paper["table"], command.lines(paper)) == (
        "table4-grids-paper", ["python -m bench.run table4 --bake grids=paper"])
    assert command.lines(runs["table2"]) == [
        "git clone https://github.com/EricXu23/Bonsaidownload",
        "git clone https://github.com/FunnyPocketBook/sfm-ooi-extract",
        "python -m bench.tools.public_scenes bonsai Bonsaidownload sfm-ooi-extract data/bonsai",
        "python -m bench.run table2 --scene data/bonsai --downscale 2 --preset cpu-long --seeds 3"]
    commands = {}                                    # the scene tells runs of a table apart
    for data in runs.values():
        commands.setdefault(markdown.title(data), set()).add(command.lines(data)[-1])
    assert all(len(c) == 1 for c in commands.values()), commands


def test_a_stale_run_or_a_hand_edit_is_regenerated_and_text_outside_stays(tree, tmp_path):
    _edit_run(tmp_path / "runs", "table4", lambda d: d["rows"][0].update(PSNR=30.0))
    docs = tmp_path / "results.md"
    docs.write_text(docs.read_text().replace(page.end("table4-fresh"),
                                             "| hand |\n" + page.end("table4-fresh"))
                    + "\nhand-written tail\n")
    assert report.main(tree) == 0
    text = docs.read_text()
    assert "| hand |" not in text and text.endswith("\nhand-written tail\n")
    assert "| L=2 paper w/o G | 30.00 | 25.67 |" in text


def test_a_runs_conditions_give_its_seeds_wall_time_and_uncommitted_changes(tmp_path):
    data = json.loads((RUNS / "table4.json").read_text())
    assert "1 seed (0)" in markdown.conditions(data)
    assert "uncommitted" not in markdown.conditions(data)
    for row in data["rows"]:
        row["seeds"] = [0, 1, 2]
    del data["wall_s"]
    data["git_revision"] += "+dirty"
    line = markdown.conditions(data)
    assert "3 seeds (0, 1, 2), `cpu` preset" in line and "wall time not recorded" in line
    assert "+dirty (**uncommitted changes**: not reproducible from a commit)" in line
    assert "(**uncommitted changes**)" in summary._named(data)


@pytest.mark.parametrize("content, error", [
    ("{not json", "bad.json: not a table written by bench.run (Expecting property name"),
    (json.dumps({"title": "t", "rows": [{}]}), "bad.json: not a table written by bench.run (no ["),
    ("BASE-resolution", "bad.json: not a table written by bench.run (no ['resolution'])"),
    ("BASE-time_ms", "bad.json: not a table written by bench.run (KeyError: 'time_ms')"),
    ("BASE-argv", "bad.json: not a table written by bench.run (no ['argv']"),
])
def test_bad_json_is_an_error_naming_the_file_and_nothing_is_written(tree, tmp_path, capsys,
                                                                     content, error):
    runs, docs = tmp_path / "runs", tmp_path / "results.md"
    if content.startswith("BASE-"):
        base = json.loads((runs / "table4.json").read_text())
        field = content.removeprefix("BASE-")
        base.pop(field) if field in base else [r.pop(field) for r in base["rows"]]
        content = json.dumps(base)
    (runs / "bad.json").write_text(content)
    docs.write_text(docs.read_text() + f"\n{page.begin('bad')}\n{page.end('bad')}\n")
    before = docs.read_text(), (tmp_path / "README.md").read_text()
    assert report.main(tree) == 2
    assert f"{runs / 'bad.json'}" in (err := capsys.readouterr().err) and error in err
    assert (docs.read_text(), (tmp_path / "README.md").read_text()) == before


@pytest.mark.parametrize("edit, error", [
    (lambda t: t.replace(page.end("table4-bonsai"), ""),
     "table4-bonsai: expected a begin and an end"),
    (lambda t: t + f"{page.begin('gone')}\n{page.end('gone')}\n", "blocks gone have no"),
    (lambda t: t.replace(page.begin("table4-bonsai"), "").replace(page.end("table4-bonsai"), ""),
     "table4-bonsai.json: no block in"),
    (lambda t: t + f"{page.begin('table4')}\n{page.end('table4')}\n",
     "expected one <!-- results:table4"),
])
def test_blocks_and_runs_must_match_one_to_one(tree, tmp_path, capsys, edit, error):
    docs = tmp_path / "results.md"
    docs.write_text(edit(docs.read_text()))
    assert report.main(tree) == 2
    assert error in capsys.readouterr().err


def test_pages_are_written_atomically(tree, tmp_path, monkeypatch, capsys):
    _edit_run(tmp_path / "runs", "table4",                 # in the README's summary too
              lambda d: d["comparisons"][0].update(mean=d["comparisons"][0]["mean"] + 1.0))
    written = []
    for module in (report, summary):
        monkeypatch.setattr(module, "write_atomic",
                            lambda path, text, real=module.write_atomic: written.append(
                                Path(path).name) or real(path, text))
    assert report.main(tree) == 0
    assert sorted(written) == ["README.md", "results.md"]

    def fail(src, dst):
        raise OSError(f"{dst}: disk full")

    _edit_run(tmp_path / "runs", "table4", lambda d: d.update(device="a third device"))
    before = {f: (tmp_path / f).read_text() for f in ("README.md", "results.md")}
    monkeypatch.setattr(os, "replace", fail)
    assert report.main(tree) == 2 and "disk full" in capsys.readouterr().err
    assert {f: (tmp_path / f).read_text() for f in before} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["README.md", "results.md", "runs"]
