"""densetact.calibrate, label_session and read_frame: the dataset tool's first steps."""

import json

import numpy as np
import pytest

import densetact


def test_calibration_finds_the_units_fisheye(session, tmp_path):
    cal = densetact.calibrate(session / "sawtooth.png")
    truth = json.loads((session / ".simulation" / "truth.json").read_text())
    got, true = cal.sensor["correspondence"], truth["correspondence"]
    assert abs(got["centre_u_px"] - true["centre_u_px"]) < 1.0
    assert abs(got["centre_v_px"] - true["centre_v_px"]) < 1.0
    assert cal.edges >= 20 and 0 < cal.uncertainty_px <= 0.5
    # An array gives what its file gives.
    again = densetact.calibrate(densetact.read_frame(session / "sawtooth.png"))
    assert again.sensor == cal.sensor
    path = tmp_path / "sensor.json"
    cal.save(path)
    assert json.loads(path.read_text()) == cal.sensor

    noise = np.random.default_rng(0).integers(0, 255, (600, 800, 3), dtype=np.uint8)
    with pytest.raises(densetact.DenseTactError, match="calibration failed"):
        densetact.calibrate(noise)
    with pytest.raises(ValueError, match="90 degrees"):
        densetact.calibrate(noise, pitch_deg=10.0, teeth=17)


def test_a_session_is_labelled_into_a_dataset(session, rows, tmp_path):
    cal = densetact.calibrate(session / "sawtooth.png")
    out = tmp_path / "labelled"
    ds = densetact.label_session(session, cal, out)
    assert len(ds) == len(rows) and ds.report
    image, depth, record = ds[0]
    assert image.shape == (cal.sensor["crop_size_px"],) * 2 + (3,)
    assert record["capture"]["frame"] in {r["frame"] for r in rows}
    assert any((d > densetact.CONTACT_THRESHOLD_MM).any() for _, d, _ in ds)
    # Labelled again into its own folder: resumed, the same samples.
    again = densetact.label_session(session, cal.sensor, out)
    assert [r for _, _, r in again] == [r for _, _, r in ds]

    # A job array's shares hold the rows dealt to them, together all of them.
    shares = [densetact.label_session(session, cal, tmp_path / f"share{k}", shard=f"{k}/2") for k in range(2)]
    assert [len(s) for s in shares] == [(len(rows) + 1) // 2, len(rows) // 2]
    assert sorted(r["id"] for s in shares for _, _, r in s) == sorted(r["id"] for _, _, r in ds)
    with pytest.raises(ValueError, match="shard"):
        densetact.label_session(session, cal, tmp_path / "x", shard="2/2")

    with pytest.raises(ValueError, match="on_bad_row must be one of stop, skip"):
        densetact.label_session(session, cal, tmp_path / "x", on_bad_row="ignore")
    with pytest.raises(ValueError, match="z_from"):
        densetact.label_session(session, cal, tmp_path / "x", z_from="somewhere")
    with pytest.raises(densetact.DenseTactError, match="no-such-session"):
        densetact.label_session(tmp_path / "no-such-session", cal, tmp_path / "y")
    stranger = tmp_path / "stranger"
    stranger.mkdir()
    (stranger / "notes.txt").write_text("mine")
    with pytest.raises(densetact.DenseTactError, match="stranger"):
        densetact.label_session(session, cal, stranger)
    assert (stranger / "notes.txt").read_text() == "mine"
    with pytest.raises(densetact.DenseTactError, match="sensor.json"):
        densetact.label_session(session, tmp_path / "sensor.json", tmp_path / "z")
