"""densetact.Dataset: a dataset folder's samples, and PyTorch's DataLoader over them."""

import json
import pickle

import numpy as np
import pytest

import densetact
from conftest import peer


def test_samples_are_images_depths_and_records(root):
    data = root / "data"
    manifest = json.loads((data / "manifest.json").read_text())
    ds = densetact.Dataset(data)
    train, test = densetact.Dataset(data, "train"), densetact.Dataset(data, split="test")
    assert len(ds) == len(manifest["samples"]) == len(train) + len(test)
    assert len(train) > 0 and len(test) > 0
    n = ds.sensor["crop_size_px"]
    seen = 0
    for (image, depth, record), expected in zip(ds, manifest["samples"]):
        assert record == expected
        assert image.dtype == np.uint8 and image.shape == (n, n, 3)
        assert depth.dtype == np.float32 and depth.shape == (n, n)
        # The record's statistics are the depth map's (micrometre PNG: within half a step).
        assert abs(depth.max() - record["stats"]["max_depth_mm"]) <= 5e-4
        pressure = ds.pressure(seen)
        assert pressure.shape == (n, n) and (pressure >= 0).all()
        # Pressure where the indenter presses, none on an untouched frame.
        if depth.max() == 0:
            assert not pressure.any()
        if depth.max() > 0.1:
            assert pressure.any() and np.linalg.norm(record["wrench"]["force_n"]) > 0
        assert ds.reference(seen).shape == (n, n, 3)
        seen += 1
    assert seen == len(ds)
    assert all(r["split"] == "test" for _, _, r in test)
    assert np.array_equal(ds[-1][1], ds[len(ds) - 1][1])
    # Pickled (for a DataLoader's spawned workers), it reads the same samples.
    copy = pickle.loads(pickle.dumps(test))
    assert len(copy) == len(test) and np.array_equal(copy[0][0], test[0][0]) and copy.record(0) == test.record(0)
    with pytest.raises(IndexError):
        ds[len(ds)]
    with pytest.raises(TypeError):
        ds["0"]
    with pytest.raises(ValueError, match="split"):
        densetact.Dataset(data, "validation")
    with pytest.raises(densetact.DenseTactError, match="manifest.json"):
        densetact.Dataset(root / "bundle")


def test_a_missing_file_is_named(root, tmp_path):
    import shutil

    copy = tmp_path / "data"
    shutil.copytree(root / "data", copy)
    record = densetact.Dataset(copy).record(0)
    (copy / record["depth"]).unlink()
    with pytest.raises(densetact.DenseTactError, match=record["depth"]):
        densetact.Dataset(copy)[0]


def test_a_dataloader_trains_a_few_pytorch_steps(root):
    torch = peer("torch")
    from torch.utils.data import DataLoader

    ds = densetact.Dataset(root / "data", "train")
    loader = DataLoader(ds, batch_size=2, shuffle=True, collate_fn=densetact.collate)
    torch.manual_seed(0)
    net = torch.nn.Sequential(
        torch.nn.AvgPool2d(8), torch.nn.Conv2d(3, 8, 3, padding=1), torch.nn.ReLU(), torch.nn.Conv2d(8, 1, 3, padding=1)
    )
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    losses = []
    for _ in range(4):
        for images, depths, records in loader:
            x = torch.from_numpy(images).permute(0, 3, 1, 2).float() / 255.0
            y = torch.nn.functional.avg_pool2d(torch.from_numpy(depths)[:, None], 8)
            loss = torch.nn.functional.l1_loss(net(x), y)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(loss.item())
            assert len(records) == len(images) and all("scene" in r for r in records)
    assert all(np.isfinite(losses))
    assert np.mean(losses[-3:]) < np.mean(losses[:3]), losses
