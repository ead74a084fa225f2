"""Built-in scene generator: determinism, image content, loading back, scene bounds."""
import json

import numpy as np
import pytest

from clrender.camera import generate_rays
from clrender.data import load_dataset, make_scene

SIZE, N_TRAIN, N_TEST = 48, 4, 2


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """Both kinds, each generated twice with the same seed: {kind: (folder, folder again)}."""
    root = tmp_path_factory.mktemp("scenes")
    return {kind: tuple(make_scene(kind, root / f"{kind}{k}", seed=3, n_train=N_TRAIN,
                                   n_test=N_TEST, width=SIZE, height=SIZE) for k in range(2))
            for kind in ("bounded", "unbounded")}


@pytest.mark.parametrize("kind", ["bounded", "unbounded"])
def test_deterministic(scenes, kind):
    a, b = scenes[kind]
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert len(files) == 3 + N_TRAIN + N_TEST
    assert not any(p.name.endswith(".tmp") for p in files)
    for rel in files:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel


@pytest.mark.parametrize("kind", ["bounded", "unbounded"])
def test_loads_back(scenes, kind):
    folder = scenes[kind][0]
    meta = json.loads((folder / "transforms_train.json").read_text())
    assert meta["clrender"] == {"scene": kind, "scale": 1.0, "seed": 3, "supersample": 8}
    train, test = load_dataset(folder, "train"), load_dataset(folder, "test")
    assert train.images.shape == (N_TRAIN, SIZE, SIZE, 3) and len(test.cameras) == N_TEST
    assert train.scene == test.scene == kind
    np.testing.assert_allclose(train.cameras[2].c2w, meta["frames"][2]["transform_matrix"])
    assert (load_dataset(folder, "val").images == test.images).all()
    if kind == "bounded":
        assert train.alpha is not None and 0.05 < train.alpha.mean() < 0.9
    else:
        assert train.alpha is None  # RGB images: every pixel hits something
        radius = np.linalg.norm([c.origin[:2] for c in train.cameras], axis=1)
        assert np.all((radius >= 1.0) & (radius <= 1.3))


@pytest.mark.parametrize("kind", ["bounded", "unbounded"])
def test_images_textured_with_highlights(scenes, kind):
    ds = load_dataset(scenes[kind][0], "train")
    covered = ds.alpha > 0.99 if ds.alpha is not None else np.ones(ds.images.shape[:3], bool)
    for img, mask in zip(ds.images, covered):
        # Texture contrast: neighbouring covered pixels differ noticeably on average.
        both = mask[:, 1:] & mask[:, :-1]
        step = np.abs(img[:, 1:] - img[:, :-1]).mean(-1)[both]
        assert step.mean() > 0.04 and img[mask].std(0).mean() > 0.1
    # Albedos are saturated (every colour has a channel <= 0.25, grain <= 1.25), so pixels
    # with every channel above 0.8 are specular highlights.
    assert np.sum(covered & (ds.images.min(-1) > 0.8)) >= 2


def test_bounded_content_inside_unit_cube(scenes):
    ds = load_dataset(scenes["bounded"][0], "train")
    misses = 0
    for cam, alpha in zip(ds.cameras, ds.alpha):
        o, d = generate_rays(cam)
        with np.errstate(divide="ignore"):
            t0, t1 = (-1 - o) / d, (1 - o) / d
        near = np.minimum(t0, t1).max(-1)
        far = np.maximum(t0, t1).min(-1)
        miss = near >= far
        misses += miss.sum()
        assert np.all(alpha[miss] == 0)
    assert misses > 0


def test_bad_kind(tmp_path):
    with pytest.raises(ValueError, match="scene kind must be 'bounded' or 'unbounded'"):
        make_scene("forest", tmp_path)
