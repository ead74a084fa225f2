"""Baked NGP-RT file: round trip, rejection of malformed files, occupancy structures."""
import itertools
import json
from dataclasses import replace

import numpy as np
import pytest

from clrender.ngprt.baked import (FORMAT, VERSION, BakedFormatError, BakedModel, build_distance_grid,
                                  build_mip, load_baked, save_baked, sparse_coarse_grid, validate)
from clrender.ngprt.config import SCENES, VARIANTS, preset
from clrender.ngprt.random_model import random_baked_model


def small(**kw):
    return preset("tiny", **{"L_C": 16, "G_res": 8, "log2_T": 10, **kw})


@pytest.fixture(scope="module")
def model():
    return random_baked_model(small(variant="separate-v"), seed=1, gamma=1.25)


def write_raw(path, arrays, manifest=None, **manifest_overrides):
    """An .npz written without validation, manifest listing ``arrays`` unless given."""
    if manifest is None:
        manifest = {"format": FORMAT, "version": VERSION, "config": small().to_dict(),
                    "gamma": 1.0, "G_metric": "box",
                    "arrays": {n: {"shape": list(a.shape), "dtype": str(a.dtype)}
                               for n, a in arrays.items()}}
    manifest.update(manifest_overrides)
    np.savez(path, manifest=np.array(json.dumps(manifest)), **arrays)
    return path


def raw_from(model):
    arrays = {n: a.copy() for n, a in model.arrays.items()}
    manifest = {"format": FORMAT, "version": VERSION, "config": model.config.to_dict(),
                "gamma": model.gamma, "G_metric": model.G_metric}
    return arrays, manifest


def listing(arrays):
    return {n: {"shape": list(a.shape), "dtype": str(a.dtype)} for n, a in arrays.items()}


def test_round_trip(model, tmp_path):
    path = save_baked(model, tmp_path / "m.npz")
    assert path == tmp_path / "m.npz" and not list(tmp_path.glob("*.tmp"))
    back = load_baked(path)
    assert back.config == model.config and back.gamma == model.gamma
    assert back.step == model.step == float(np.float32(1.25 * model.config.s0))
    assert set(back.arrays) == set(model.arrays)
    for name, a in model.arrays.items():
        assert back.arrays[name].dtype == a.dtype and np.array_equal(back.arrays[name], a), name
    assert [m.shape[0] for m in back.occupancy_mip()] == [16, 8, 4, 2, 1]


def test_step_res_sets_the_step_and_round_trips(model, tmp_path):
    assert model.config.step_res is None     # the paper's s0 = 2 sqrt(3) / L_C
    assert model.config.s0 == 2 * np.sqrt(3) / model.config.L_C
    finer = replace(model, config=replace(model.config, step_res=4 * model.config.L_C))
    back = load_baked(save_baked(finer, tmp_path / "m.npz"))
    assert back.config.step_res == 4 * model.config.L_C
    assert back.step == float(np.float32(1.25 * 2 * np.sqrt(3) / (4 * model.config.L_C)))


def _corrupt(arrays, manifest, case):
    """Apply one corruption; returns the expected message fragment."""
    if case == "wrong dtype":
        arrays["fine_tables"] = arrays["fine_tables"].astype(np.float64)
        return "fine_tables has dtype float64, expected float32"
    if case == "nan":
        arrays["coarse_blocks"][0, 1, 2, 3, 0] = np.nan
        return "coarse_blocks has 1 non-finite"
    if case == "block index out of range":
        idx = arrays["coarse_block_index"]
        idx[tuple(np.argwhere(idx >= 0)[0])] = arrays["coarse_blocks"].shape[0]
        return "coarse_block_index has values in"
    if case == "unknown version":
        manifest["version"] = 4
        return "unknown version 4"
    if case == "no G metric":
        del manifest["G_metric"]
        return "manifest has no 'G_metric'"
    if case == "unknown G metric":
        manifest["G_metric"] = "chebyshev"
        return "G_metric 'chebyshev'"
    if case == "wrong format name":
        manifest["format"] = "something-else"
        return "format is 'something-else'"
    if case == "missing array":
        del arrays["G"]
        return "missing arrays ['G']"
    if case == "wrong shape":
        arrays["fine_tables"] = arrays["fine_tables"][..., :7].copy()
        return "fine_tables has shape (2, 1024, 7), expected (2, 1024, 8)"
    if case == "extra array":
        arrays["attention_inv"] = np.zeros(4, np.float32)
        return "unexpected arrays ['attention_inv']"
    if case == "mip inconsistent":
        arrays["occupancy_2"][:] = 0
        return "occupancy_2 is not the 2x max-pool"
    if case == "G not conservative":
        arrays["G"][:] = 3
        return "G exceeds its box metric's bound"
    if case == "G past the centre bound":
        manifest["G_metric"] = "centre"
        arrays["G"][:] = 3
        return "G exceeds its centre metric's bound"
    if case == "bad config":
        manifest["config"] = dict(manifest["config"], L_C=17)
        return "bad config"
    raise AssertionError(case)


CASES = ["wrong dtype", "nan", "block index out of range", "unknown version", "no G metric",
         "unknown G metric", "wrong format name", "missing array", "wrong shape", "extra array",
         "mip inconsistent", "G not conservative", "G past the centre bound", "bad config"]


@pytest.mark.parametrize("case", CASES)
def test_malformed_rejected(model, tmp_path, case):
    arrays, manifest = raw_from(model)
    fragment = _corrupt(arrays, manifest, case)
    path = write_raw(tmp_path / f"bad_{case.replace(' ', '_')}.npz", arrays,
                     dict(manifest, arrays=listing(arrays)))
    with pytest.raises(BakedFormatError) as err:
        load_baked(path)
    assert str(path) in str(err.value) and fragment in str(err.value), str(err.value)


def test_truncated_and_not_an_archive(model, tmp_path):
    path = save_baked(model, tmp_path / "cut.npz")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(BakedFormatError, match=r"cut\.npz: not a readable \.npz archive"):
        load_baked(path)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"definitely not a zip file" * 10)
    with pytest.raises(BakedFormatError, match=r"junk\.npz: not a readable"):
        load_baked(junk)


def test_manifest_problems(model, tmp_path):
    arrays, manifest = raw_from(model)
    path = tmp_path / "nomanifest.npz"
    np.savez(path, **arrays)
    with pytest.raises(BakedFormatError, match=r"nomanifest\.npz: no 'manifest' entry"):
        load_baked(path)
    path = tmp_path / "badjson.npz"
    np.savez(path, manifest=np.array("{not json"), **arrays)
    with pytest.raises(BakedFormatError, match=r"badjson\.npz: manifest is not valid JSON"):
        load_baked(path)
    path = write_raw(tmp_path / "listing.npz", arrays, dict(manifest, arrays={}))
    with pytest.raises(BakedFormatError, match=r"listing\.npz: manifest lists arrays"):
        load_baked(path)


def test_validate_model_level_checks(model):
    bad = BakedModel(model.config, 0.0, model.arrays)
    with pytest.raises(BakedFormatError, match="gamma must be finite and > 0"):
        validate(bad, "m")
    arrays = dict(model.arrays)
    idx = arrays["coarse_block_index"].copy()
    idx[tuple(np.argwhere(idx >= 0)[0])] = -1       # an occupied block goes missing
    arrays["coarse_block_index"] = idx
    with pytest.raises(BakedFormatError, match="exactly once"):
        validate(BakedModel(model.config, 1.0, arrays), "m")
    with pytest.raises(BakedFormatError):
        save_baked(bad, "/nonexistent-dir-is-never-reached/x.npz")


def test_build_mip():
    rng = np.random.default_rng(0)
    occ = (rng.random((32, 32, 32)) < 0.002).astype(np.uint8)
    mip = build_mip(occ)
    assert [m.shape for m in mip] == [(32,) * 3, (16,) * 3, (8,) * 3, (4,) * 3, (2,) * 3]
    for lev in range(1, 5):
        f = 1 << lev
        for i in itertools.product(range(32 >> lev), repeat=3):
            block = occ[i[0] * f:(i[0] + 1) * f, i[1] * f:(i[1] + 1) * f, i[2] * f:(i[2] + 1) * f]
            assert mip[lev][i] == block.max()


@pytest.mark.parametrize("G_res", [8, 16])
def test_distance_grid_is_box_distance(G_res):
    """Brute force: G is the rounded-down box-to-box distance to the nearest occupied
    G-voxel, so no occupied voxel (as a closed box) is closer than G to any voxel."""
    rng = np.random.default_rng(G_res)
    occ = (rng.random((16, 16, 16)) < 0.004).astype(np.uint8)
    G = build_distance_grid(occ, G_res)
    f = 16 // G_res
    occ_g = occ.reshape(G_res, f, G_res, f, G_res, f).max(axis=(1, 3, 5))
    vox = np.argwhere(np.ones((G_res,) * 3, bool))
    occupied = np.argwhere(occ_g)
    gap = np.maximum(np.abs(vox[:, None, :] - occupied[None, :, :]) - 1, 0)
    box_dist = np.sqrt((gap ** 2).sum(-1)).min(axis=1)      # G-voxel units
    np.testing.assert_array_equal(G.reshape(-1), np.minimum(np.floor(box_dist), 255))
    assert np.all(G[occ_g > 0] == 0) and G.max() >= 1
    assert np.all(build_distance_grid(np.zeros_like(occ), G_res) == 255)


@pytest.mark.parametrize("G_res", [8, 16])
def test_centre_metric_is_centre_distance(G_res):
    """Brute force: the paper's G is the rounded-down distance from a voxel's centre to the
    nearest occupied G-voxel's centre, never below the box metric's."""
    rng = np.random.default_rng(G_res + 1)
    occ = (rng.random((16, 16, 16)) < 0.004).astype(np.uint8)
    G = build_distance_grid(occ, G_res, "centre")
    f = 16 // G_res
    occ_g = occ.reshape(G_res, f, G_res, f, G_res, f).max(axis=(1, 3, 5))
    vox = np.argwhere(np.ones((G_res,) * 3, bool))
    occupied = np.argwhere(occ_g)
    dist = np.sqrt(((vox[:, None, :] - occupied[None, :, :]) ** 2).sum(-1)).min(axis=1)
    np.testing.assert_array_equal(G.reshape(-1), np.minimum(np.floor(dist), 255))
    assert np.all(G >= build_distance_grid(occ, G_res)) and np.any(G > build_distance_grid(occ, G_res))
    with pytest.raises(ValueError, match="G metric 'edt'"):
        build_distance_grid(occ, G_res, "edt")


def test_centre_metric_round_trips_and_version_1_files_load_as_box(model, tmp_path):
    centre = replace(model, G_metric="centre", arrays=dict(
        model.arrays, G=build_distance_grid(model.arrays["occupancy_0"], model.config.G_res,
                                            "centre")))
    back = load_baked(save_baked(centre, tmp_path / "c.npz"))
    assert back.G_metric == "centre" and np.array_equal(back.arrays["G"], centre.arrays["G"])
    with pytest.raises(BakedFormatError, match="box metric's bound"):
        save_baked(replace(centre, G_metric="box"), tmp_path / "wrong.npz")
    arrays, manifest = raw_from(model)
    del manifest["G_metric"]
    old = write_raw(tmp_path / "v1.npz", arrays, dict(manifest, version=1,
                                                      arrays=listing(arrays)))
    assert load_baked(old).G_metric == "box"


def test_finer_occupancy_round_trips_and_older_files_load_at_L_C(model, tmp_path):
    """Version 3 holds occupancy finer than the coarse grid (the paper's grids); version 2
    files (no ``occupancy_res``) still load with occupancy at L_C."""
    fine = random_baked_model(small(occupancy_res=64, G_res=32, coarse_block=4), seed=1)
    assert fine.arrays["occupancy_0"].shape == (64,) * 3 and fine.arrays["G"].shape == (32,) * 3
    back = load_baked(save_baked(fine, tmp_path / "fine.npz"))
    assert back.config.occ_res == 64 and back.config.occ_shift == 2
    for name, a in fine.arrays.items():
        np.testing.assert_array_equal(back.arrays[name], a, err_msg=name)
    arrays, manifest = raw_from(model)
    del manifest["config"]["occupancy_res"]
    old = load_baked(write_raw(tmp_path / "v2.npz", arrays, dict(manifest, version=2,
                                                                arrays=listing(arrays))))
    assert old.config.occ_res == old.config.L_C == 16
    # A fine occupied cell outside every coarse block is refused, as at L_C.
    arrays, manifest = raw_from(fine)
    absent = np.argwhere(arrays["coarse_block_index"] < 0)[0] * 4 * 4   # block -> fine cell
    arrays["occupancy_0"][tuple(absent)] = 1
    for lev, grid in enumerate(build_mip(arrays["occupancy_0"])):
        arrays[f"occupancy_{lev}"] = grid
    arrays["G"] = build_distance_grid(arrays["occupancy_0"], 32)
    with pytest.raises(BakedFormatError, match="hold occupied occupancy_0 cells but are absent"):
        load_baked(write_raw(tmp_path / "bad.npz", arrays, dict(manifest, arrays=listing(arrays))))


@pytest.mark.parametrize("fields,message", [
    ({"occupancy_res": 48}, "must be L_C=16 times a power of two"),
    ({"occupancy_res": 8}, "must be L_C=16 times a power of two"),
    ({"occupancy_res": 2048}, "above the maximum"),
    ({"occupancy_res": 64, "G_res": 48}, "G_res=48 must divide the occupancy resolution 64"),
])
def test_occupancy_resolution_is_checked(fields, message):
    with pytest.raises(ValueError, match=message):
        small(**fields)


def test_paper_grids_replace_only_the_empty_space_grids():
    from clrender.ngprt.config import PRESETS, with_grids

    cpu = PRESETS["cpu"]
    paper = with_grids(cpu, "paper")
    assert (paper.occ_res, paper.G_res, paper.occ_shift) == (512, 256, 2)
    assert replace(paper, occupancy_res=None, G_res=cpu.G_res) == cpu
    assert with_grids(cpu, "preset") == cpu and paper.s0 == cpu.s0
    with pytest.raises(ValueError, match="grids 'huge'"):
        with_grids(cpu, "huge")


def test_sparse_coarse_grid_dense_and_callable_agree():
    rng = np.random.default_rng(3)
    occ = (rng.random((16, 16, 16)) < 0.01).astype(np.uint8)
    dense = rng.normal(size=(17, 17, 17, 5)).astype(np.float32)
    idx_a, blocks_a = sparse_coarse_grid(dense, occ, 4)
    idx_b, blocks_b = sparse_coarse_grid(lambda c: dense[c[:, 0], c[:, 1], c[:, 2]], occ, 4)
    assert np.array_equal(idx_a, idx_b) and np.array_equal(blocks_a, blocks_b)
    for i in np.argwhere(occ):                      # corner i + c of the block of cell i
        b = idx_a[tuple(i // 4)]
        assert b >= 0
        for c in itertools.product((0, 1), repeat=3):
            j = i % 4 + c
            assert np.array_equal(blocks_a[b, j[0], j[1], j[2]], dense[tuple(i + c)])
    idx0, blocks0 = sparse_coarse_grid(lambda c: 1 / 0, np.zeros_like(occ), 4, channels=5)
    assert np.all(idx0 == -1) and blocks0.shape == (0, 5, 5, 5, 5)


@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("variant", VARIANTS)
def test_random_models_validate(variant, scene):
    cfg = small(variant=variant, scene=scene, L=3)
    m = random_baked_model(cfg, seed=5)
    validate(m)
    occ = m.arrays["occupancy_0"]
    assert 0.005 < occ.mean() < 0.5 and m.arrays["G"].max() >= 1
    if scene == "unbounded":       # content in the contracted outer shell |c|_inf in (1, 2)
        c = (np.argwhere(occ) + 0.5) / 16 * 4 - 2
        assert np.any(np.abs(c).max(axis=1) > 1.0)


def test_random_model_deterministic():
    a, b = (random_baked_model(small(), seed=7) for _ in range(2))
    c = random_baked_model(small(), seed=8)
    assert all(np.array_equal(a.arrays[n], b.arrays[n]) for n in a.arrays)
    assert not np.array_equal(a.arrays["occupancy_0"], c.arrays["occupancy_0"])
