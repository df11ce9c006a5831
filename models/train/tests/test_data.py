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
    Target,
    disparity_from_depth,
    list_examples,
    load_example,
    make_sample,
    pick_targets,
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


def multi_example(count=3, h=16, w=16):
    """fake_example with `count` targets, each its own image, mask and offset."""
    rng = np.random.default_rng(1)
    ex = fake_example(h, w)
    extra = []
    for k in range(1, count):
        mask = np.ones((h, w), bool)
        mask[k, : 2 * k] = False
        offset = np.array([0.1 * k, -0.2 + 0.05 * k, 0.03 * k], np.float32)
        extra.append(Target(rng.uniform(0, 0.3, (h, w, 3)).astype(np.float16), mask, offset))
    ex.reshaded = rng.uniform(0, 0.3, (h, w, 3)).astype(np.float16)
    ex.extra = tuple(extra)
    return ex


def single(ex, k):
    """Target k of `ex` as a one-target example."""
    t = ex.target(k)
    return Example(ex.name, ex.input, t.reshaded, ex.disparity, t.mask, t.offset, ex.scene,
                   ex.intrinsics)  # fmt: skip


@pytest.mark.parametrize("dihedral", [False, True])
def test_every_augmentation_treats_all_targets_as_it_treats_one(dihedral):
    """Target k of a multi-target sample is exactly the sample of the one-target example k
    drawn with the same random numbers: the same crop, tone mapping, disparity scale,
    flips and transpose, with its camera offset moved to match."""
    ex = multi_example()
    aug = Augment(still=0.0, dihedral=dihedral)
    flips = set()
    for seed in range(16):
        s = make_sample(ex, 12, np.random.default_rng(seed), aug, targets=3)
        assert s["targets"].shape == (3, 3, 12, 12) and s["masks"].shape == (3, 1, 12, 12)
        assert s["cameras"].shape == (3, 3) and torch.equal(s["weights"], torch.ones(3))
        for k in range(3):
            one = make_sample(single(ex, k), 12, np.random.default_rng(seed), aug)
            for key in ("image", "disparity", "rays"):
                assert torch.equal(s[key], one[key])
            assert torch.equal(s["targets"][k], one["target"])
            assert torch.equal(s["masks"][k], one["mask"])
            assert torch.equal(s["cameras"][k], one["camera"])
        d = s["disparity"][0]
        flips.add((bool(d[0, 1] > d[0, 0]), bool(d[1, 0] > d[0, 0])))  # which way it grows
    assert len(flips) == (4 if dihedral else 2)


def test_a_flipped_sample_flips_every_target_and_negates_every_tx():
    ex = multi_example()
    aug = Augment(still=0.0, disparity_scale=(1.0, 1.0), exposure=(4.0, 4.0), gamma=(2.2, 2.2))
    plain = make_sample(ex, None, None, None, targets=3)
    offsets = np.stack([ex.target(k).offset for k in range(3)])
    seen = set()
    for seed in range(10):
        s = make_sample(ex, None, np.random.default_rng(seed), aug, targets=3)
        d = s["disparity"][0]
        flipped = bool(d[0, 1] < d[0, 0])  # the disparity ramp runs the other way
        seen.add(flipped)
        for k in range(3):
            image = tonemap(ex.target(k).reshaded.astype(np.float32), 4.0, 2.2)
            image = image[:, ::-1] if flipped else image
            assert np.allclose(s["targets"][k].numpy(), image.transpose(2, 0, 1), atol=1e-6)
            mask = ex.target(k).mask[:, ::-1] if flipped else ex.target(k).mask
            assert np.array_equal(s["masks"][k, 0].numpy() > 0, mask)
        sign = np.array([-1.0 if flipped else 1.0, 1.0, 1.0], np.float32)
        assert np.allclose(s["cameras"].numpy(), offsets * sign)
    assert seen == {False, True}
    assert torch.allclose(plain["cameras"], torch.from_numpy(offsets))


def test_targets_are_drawn_without_replacement_or_padded():
    rng = np.random.default_rng(0)
    picks, weights = pick_targets(1, None, rng)
    assert picks == [0] and weights is None
    for _ in range(10):
        picks, weights = pick_targets(5, 3, rng)
        assert len(set(picks)) == 3 and weights.tolist() == [1, 1, 1]
    assert pick_targets(5, 3, None)[0] == [0, 1, 2]
    picks, weights = pick_targets(2, 4, rng)
    assert picks == [0, 1, 0, 0] and weights.tolist() == [1, 1, 0, 0]
    # A one-target example draws no random number: old data samples as it always did.
    state = rng.bit_generator.state
    pick_targets(1, 1, rng)
    assert rng.bit_generator.state == state
    with pytest.raises(ValueError, match="at least 1"):
        pick_targets(2, 0, rng)


def test_one_target_sample_with_targets_matches_the_plain_sample():
    ex = fake_example()
    aug = Augment(dihedral=True)
    for seed in range(6):
        plain = make_sample(ex, 8, np.random.default_rng(seed), aug)
        one = make_sample(ex, 8, np.random.default_rng(seed), aug, targets=1)
        assert torch.equal(one["targets"][0], plain["target"])
        assert torch.equal(one["cameras"][0], plain["camera"])
        assert torch.equal(one["masks"][0], plain["mask"])
        padded = make_sample(ex, 8, np.random.default_rng(seed), aug, targets=3)
        assert torch.equal(padded["targets"][0], plain["target"])
        assert padded["weights"].tolist() == [1.0, 0.0, 0.0]


def test_still_is_drawn_per_target():
    ex = multi_example()
    s = make_sample(ex, None, np.random.default_rng(0), Augment(still=1.0), targets=3)
    assert torch.count_nonzero(s["cameras"]) == 0 and bool(s["masks"].all())
    for k in range(3):
        assert torch.equal(s["targets"][k], s["image"])
    kinds = set()
    for seed in range(30):
        s = make_sample(ex, None, np.random.default_rng(seed), Augment(still=0.5), targets=3)
        kinds.add(tuple(bool(c.any()) for c in s["cameras"]))
    assert len(kinds) > 2
