import json

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from reshader_train.data import (
    Augment,
    DatasetError,
    Example,
    ReshadeDataset,
    disparity_from_depth,
    list_examples,
    load_example,
    make_sample,
    pixel_rays,
)
from reshader_train.synthetic import write_dataset, write_exr
from reshader_train.tonemap import EVAL_EXPOSURE, EVAL_GAMMA, tonemap


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    root = write_dataset(tmp_path_factory.mktemp("ds"), 4, 32, 48, seed=3)
    (root / "no-meta-yet").mkdir()
    return root


def test_lists_only_complete_examples(root):
    names = [p.name for p in list_examples(root)]
    assert names == ["00000", "00001", "00002", "00003"]


def test_missing_or_empty_folder_is_an_error(tmp_path):
    with pytest.raises(DatasetError, match="does not exist"):
        list_examples(tmp_path / "nope")
    with pytest.raises(DatasetError, match="no complete examples"):
        list_examples(tmp_path)


def test_disparity_contract():
    depth = np.array([[0.1, 0.25, 1.0, np.inf], [0.0, -1.0, np.nan, 4.0]], np.float32)
    d = disparity_from_depth(depth)
    assert np.allclose(d, [[1.0, 1.0, 0.25, 0.0], [0.0, 0.0, 0.0, 0.0625]])


def test_load_example(root):
    ex = load_example(root / "00001")
    assert ex.input.shape == (32, 48, 3) and ex.reshaded.shape == (32, 48, 3)
    assert ex.mask.dtype == bool and not ex.mask[:, :2].any() and ex.mask[:, 2:].all()
    assert np.all(ex.disparity[:8] == 0.0)  # the synthetic sky is a miss (inf depth)
    meta = json.loads((root / "00001" / "meta.json").read_text())
    assert np.allclose(ex.offset, meta["novel_offset"])


def test_bad_files_are_named(tmp_path, root):
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(root / "00000", bad)
    (bad / "depth.exr").write_bytes(b"not an exr")
    with pytest.raises(DatasetError, match="depth.exr"):
        load_example(bad)
    shutil.copy(root / "00001" / "depth.exr", bad / "depth.exr")
    (bad / "meta.json").write_text("{}")
    with pytest.raises(DatasetError, match="meta.json.*novel_offset"):
        load_example(bad)
    (bad / "meta.json").write_text(json.dumps({"novel_offset": [0, 0, 0]}))
    with pytest.raises(DatasetError, match="meta.json.*input_camera"):
        load_example(bad)
    camera = {"fx": 40.0, "fy": 40.0, "cx": 23.5, "cy": 15.5}
    (bad / "meta.json").write_text(json.dumps({"novel_offset": [0, 0, 0], "input_camera": camera}))
    write_exr(bad / "reshaded.exr", {c: np.zeros((8, 8)) for c in "RGB"})
    with pytest.raises(DatasetError, match="reshaded.exr.*differs"):
        load_example(bad)


def fake_example(h=16, w=16):
    rng = np.random.default_rng(0)
    hdr = rng.uniform(0, 0.2, (h, w, 3)).astype(np.float16)
    return Example(
        name="fake",
        input=hdr,
        reshaded=hdr.copy(),
        disparity=np.linspace(0.01, 0.4, h * w, dtype=np.float32).reshape(h, w),
        mask=np.ones((h, w), bool),
        offset=np.array([0.2, -0.1, 0.05], np.float32),
        scene="fake",
        intrinsics=(20.0, 20.0, (w - 1) / 2, (h - 1) / 2),
    )


def test_augmentation_is_consistent():
    ex = fake_example()
    for seed in range(5):
        s = make_sample(ex, None, np.random.default_rng(seed), Augment(flip=False, still=0.0))
        # Same exposure and gamma on both: identical HDR gives identical LDR.
        assert torch.equal(s["image"], s["target"])
        assert 0.0 <= float(s["image"].min()) and float(s["image"].max()) <= 1.0
        # Disparity scaled by f, camera by 1/f.
        f = float(s["disparity"][0, 0, 0]) / float(ex.disparity[0, 0])
        assert 0.5 <= f <= 2.0
        unclamped = s["disparity"][0] < 1.0
        assert torch.allclose(
            s["disparity"][0][unclamped], f * torch.from_numpy(ex.disparity)[unclamped], rtol=1e-5
        )
        assert torch.allclose(s["camera"] * f, torch.from_numpy(ex.offset), rtol=1e-5)


def test_still_samples_are_the_photo_from_its_own_camera():
    ex = fake_example()
    ex.reshaded[:] = ex.input * 1.5  # a change that a still sample must not carry
    ex.mask[0, 0] = False
    s = make_sample(ex, None, np.random.default_rng(0), Augment(still=1.0))
    assert torch.equal(s["target"], s["image"])
    assert torch.count_nonzero(s["camera"]) == 0 and bool(s["mask"].all())
    moved = make_sample(ex, None, np.random.default_rng(0), Augment(still=0.0))
    assert not torch.equal(moved["target"], moved["image"])


def test_flip_mirrors_image_and_camera():
    ex = fake_example()
    flipped = None
    for seed in range(20):
        s = make_sample(ex, None, np.random.default_rng(seed), Augment(disparity_scale=(1.0, 1.0)))
        if s["camera"][0] < 0:
            flipped = s
            break
    assert flipped is not None
    assert torch.allclose(flipped["disparity"][0], torch.from_numpy(ex.disparity[:, ::-1].copy()))
    assert torch.allclose(flipped["camera"][1:], torch.from_numpy(ex.offset[1:]))


def test_dihedral_moves_the_camera_with_the_image():
    ex = fake_example()
    d, (tx, ty, tz) = ex.disparity, ex.offset
    # Each y mirror / transpose of the planes, with the camera it implies (x right, y down).
    expected = {
        "none": (d, (tx, ty)),
        "y mirror": (d[::-1], (tx, -ty)),
        "transpose": (d.T, (ty, tx)),
        "y mirror, transpose": (d[::-1].T, (-ty, tx)),
    }
    aug = Augment(disparity_scale=(1.0, 1.0), flip=False, still=0.0, dihedral=True)
    seen = set()
    for seed in range(40):
        s = make_sample(ex, None, np.random.default_rng(seed), aug)
        match = [
            k for k, (plane, cam) in expected.items()
            if np.array_equal(s["disparity"][0].numpy(), plane)
            and np.allclose(s["camera"].numpy(), [*cam, tz])
        ]  # fmt: skip
        assert len(match) == 1, f"seed {seed}: camera {s['camera']} matches no symmetry"
        seen.add(match[0])
    assert seen == set(expected)


def test_dihedral_never_transposes_a_non_square_sample():
    ex = fake_example(16, 24)
    aug = Augment(disparity_scale=(1.0, 1.0), still=0.0, dihedral=True)
    for seed in range(20):
        s = make_sample(ex, None, np.random.default_rng(seed), aug)
        assert s["disparity"].shape == (1, 16, 24)
        assert abs(float(s["camera"][0])) == pytest.approx(0.2)


def test_evaluation_sample_uses_fixed_tone_mapping(root):
    ex = load_example(root / "00002")
    s = make_sample(ex, None, None, None)
    expected = tonemap(ex.input.astype(np.float32), EVAL_EXPOSURE, EVAL_GAMMA).transpose(2, 0, 1)
    assert np.allclose(s["image"].numpy(), expected)
    assert torch.allclose(s["camera"], torch.from_numpy(ex.offset))
    with pytest.raises(DatasetError, match="crop 64 larger"):
        make_sample(ex, 64, None, None)


def test_loader_with_a_worker_gives_random_crops(root):
    ds = ReshadeDataset(root, crop=16, augment=Augment())
    torch.manual_seed(0)
    batch = next(iter(DataLoader(ds, batch_size=4, num_workers=1)))
    assert batch["image"].shape == (4, 3, 16, 16)
    assert batch["disparity"].shape == (4, 1, 16, 16)
    assert batch["mask"].shape == (4, 1, 16, 16)
    assert batch["camera"].shape == (4, 3)
    again = next(iter(DataLoader(ds, batch_size=4, num_workers=1)))
    assert not torch.equal(batch["image"], again["image"])  # new epoch seeds, new crops


def test_scene_names_for_grouping():
    from reshader_train.data import scene_name

    assert scene_name({"scene": {"kind": "room", "max_depth": 6}}) == "room"
    assert scene_name({"scene": {"kind": "file", "file": "/x/veach-ajar.xml"}}) == "veach-ajar"
    assert scene_name({"scene": "bathroom"}) == "bathroom"
    assert scene_name({}) == "all"


def test_rays_of_a_centred_square_survive_every_symmetry():
    """A centred square camera is symmetric under the eight symmetries, so every augmented
    sample's rays must be the untouched image's: K^-1 [u, v, 1] of its own pixel grid."""
    ex = fake_example()
    plain = make_sample(ex, None, None, None)["rays"]
    assert plain.shape == (3, 16, 16)
    assert torch.allclose(plain[:, 0, 0], torch.tensor([-7.5 / 20, -7.5 / 20, 1.0]))
    aug = Augment(disparity_scale=(1.0, 1.0), still=0.0, dihedral=True)
    for seed in range(16):
        s = make_sample(ex, None, np.random.default_rng(seed), aug)
        assert torch.allclose(s["rays"], plain), f"seed {seed}"


def test_rays_follow_the_crop_window():
    ex = fake_example()
    s = make_sample(ex, 8, None, None)
    y0, x0 = (16 - 8) // 2, (16 - 8) // 2
    expected = pixel_rays(ex.intrinsics, y0, x0, 8, 8)
    assert torch.allclose(s["rays"], torch.from_numpy(expected.transpose(2, 0, 1).copy()))
    assert float(s["rays"][0, 0, 0]) == pytest.approx((x0 - 7.5) / 20)
