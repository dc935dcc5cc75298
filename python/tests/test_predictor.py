"""densetact.Predictor against `infer predict`, and its handling of frames."""

import threading

import numpy as np
import pytest

import densetact


def read_ply(path):
    """The binary little-endian float x, y, z PLY that `infer predict --ply` writes."""
    data = path.read_bytes() if hasattr(path, "read_bytes") else open(path, "rb").read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode()
    n = int(next(line.split()[2] for line in header.splitlines() if line.startswith("element vertex")))
    points = np.frombuffer(data[end:], dtype="<f4").reshape(-1, 3)
    assert len(points) == n
    return points


def test_predictions_equal_infer_predict_bit_for_bit(bundle, cases):
    p = densetact.Predictor(bundle)
    ran = 0
    for case in cases:
        expected = np.load(case["depth_npy"])
        for frame in (case["frame"], densetact.read_frame(case["frame"])):
            got = p.predict(frame)
            assert got.depth_mm.dtype == np.float32 and got.depth_mm.shape == (p.crop_size_px,) * 2
            assert np.array_equal(got.depth_mm, expected), case["frame"]
            assert np.array_equal(got.points_mm, read_ply(case["ply"])), case["frame"]
            assert np.array_equal(got.contact, got.depth_mm > densetact.CONTACT_THRESHOLD_MM)
            assert not got.depth_mm[~p.mask].any(), "zero outside the useful disk"
            assert got.force is None and not p.has_force
        ran += got.network_ran
    assert ran > 0, "the frames with contact ran the network"


def test_full_frame_and_crop_agree_and_the_batch_equals_single_frames(bundle, cases):
    p = densetact.Predictor(bundle)
    full = densetact.read_frame(cases[0]["frame"])
    x, y = p.crop_origin_px
    n = p.crop_size_px
    crop = full[y : y + n, x : x + n]
    assert crop.shape == (n, n, 3) and full.shape != crop.shape
    assert np.array_equal(p.predict(full).depth_mm, p.predict(crop).depth_mm)
    # A non-contiguous view reads as its copy.
    assert np.array_equal(p.predict(crop).depth_mm, p.predict(np.ascontiguousarray(crop)).depth_mm)

    frames = [densetact.read_frame(c["frame"]) for c in cases] + [densetact.read_frame(cases[0]["frame"])]
    batch = p.predict_batch(frames)
    assert len(batch) == len(frames)
    for frame, b in zip(frames, batch):
        one = p.predict(frame)
        assert np.array_equal(b.depth_mm, one.depth_mm) and b.network_ran == one.network_ran
    assert p.predict_batch([]) == []


def test_the_gate_answers_untouched_frames_and_retare_moves_the_zero(bundle, session, cases):
    p = densetact.Predictor(bundle)
    reference = densetact.read_frame(session / "reference.png")
    assert p.is_tared
    quiet = p.predict(reference)
    assert not quiet.network_ran and not quiet.depth_mm.any() and quiet.points_mm.shape == (0, 3)
    assert not p.has_contact(reference)

    frame = densetact.read_frame(cases[0]["frame"])
    before = p.predict(frame, always=True).depth_mm
    p.retare(frame)
    assert p.is_tared
    assert not p.predict(frame, always=True).depth_mm.any(), "tared on a frame, that frame reads zero"
    p.retare(None)
    assert not p.is_tared
    raw = p.predict(frame, always=True).depth_mm
    assert not np.array_equal(raw, before), "the tare did something"


def test_bad_input_raises_with_the_tools_messages(bundle, root, cases):
    p = densetact.Predictor(bundle)
    frame = densetact.read_frame(cases[0]["frame"])
    with pytest.raises(TypeError, match="uint8"):
        p.predict(frame.astype(np.float32))
    with pytest.raises(TypeError, match="HxWx3"):
        p.predict(frame[..., 0])
    with pytest.raises(densetact.DenseTactError, match="10x12 px"):
        p.predict(np.zeros((12, 10, 3), np.uint8) + np.array([1, 2, 3], np.uint8))
    with pytest.raises(densetact.DenseTactError, match="BGR"):
        p.predict(np.ascontiguousarray(frame[..., ::-1]))
    with pytest.raises(densetact.DenseTactError, match="greyscale"):
        p.predict(np.repeat(frame[..., :1], 3, axis=2))
    cut = root / "cut.jpg"
    for read in (densetact.read_frame, p.predict):
        with pytest.raises(densetact.DenseTactError, match="cut.jpg"):
            read(cut)
    with pytest.raises(densetact.DenseTactError, match="frames\\[1\\]"):
        p.predict_batch([frame, np.ascontiguousarray(frame[..., ::-1])])
    with pytest.raises(densetact.DenseTactError, match="no-such-bundle"):
        densetact.Predictor(root / "no-such-bundle")
    with pytest.raises(densetact.DenseTactError, match="unknown or unavailable device"):
        densetact.Predictor(bundle, device="tpu")


def test_threads_share_a_predictor(bundle, cases):
    p = densetact.Predictor(bundle)
    frames = [densetact.read_frame(c["frame"]) for c in cases]
    expected = [p.predict(f).depth_mm for f in frames]
    results, errors = {}, []

    def work(k):
        try:
            for _ in range(2):
                results[k] = [p.predict(f).depth_mm for f in frames]
        except Exception as e:  # reported below
            errors.append(e)

    threads = [threading.Thread(target=work, args=(k,)) for k in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not errors and len(results) == 3
    for got in results.values():
        assert all(np.array_equal(a, b) for a, b in zip(got, expected))


def test_workers_polling_between_frames_change_no_prediction(bundle, cases):
    p = densetact.Predictor(bundle)
    frames = [densetact.read_frame(c["frame"]) for c in cases]
    expected = [p.predict(f).depth_mm for f in frames]
    densetact.set_spin_ms(20)
    try:
        got = [p.predict(f).depth_mm for f in frames]
    finally:
        densetact.set_spin_ms(0)
    assert all(np.array_equal(a, b) for a, b in zip(got, expected))
    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="milliseconds"):
            densetact.set_spin_ms(bad)


def test_an_elastomer_set_from_python_solves_the_predicted_contact(bundle, cases):
    p = densetact.Predictor(bundle)
    n = p.crop_size_px
    zeros = np.zeros((n, n), np.float32)
    assert p.effective_modulus_mpa is None and not p.has_force and p.force_source is None
    with pytest.raises(densetact.DenseTactError, match="set_elastomer"):
        p.solve_force(zeros)

    # A round dent at the crop's centre, 0.8 mm deep, as a network might predict it.
    y, x = np.mgrid[0:n, 0:n]
    r2 = ((x - n / 2) ** 2 + (y - n / 2) ** 2) / (n / 12) ** 2
    dent = np.where(p.mask, 0.8 * np.clip(1 - r2, 0, None), 0).astype(np.float32)
    p.set_elastomer(0.2)
    assert p.has_force and p.effective_modulus_mpa == 0.2
    assert "solved on the predicted depth" in p.force_source
    force = p.solve_force(dent)
    f = np.linalg.norm(force.force_n)
    assert f > 0.05 and force.force_n[2] < -0.9 * f, force.force_n
    assert force.pressure_kpa.shape == (n, n) and force.pressure_kpa.dtype == np.float32
    assert not force.pressure_kpa[dent <= densetact.CONTACT_THRESHOLD_MM].any(), "no pressure off the contact"
    assert not np.linalg.norm(p.solve_force(zeros).force_n), "no contact, no force"
    # Pressure scales with the modulus; the contact does not move.
    p.set_elastomer(0.4)
    twice = p.solve_force(dent)
    np.testing.assert_allclose(twice.force_n, 2 * force.force_n, rtol=1e-9)
    assert np.array_equal(twice.pressure_kpa > 0, force.pressure_kpa > 0)

    # Predictions carry the force solved on their own depth.
    got = p.predict(densetact.read_frame(cases[0]["frame"]), always=True)
    again = p.solve_force(got.depth_mm)
    assert np.array_equal(got.force.force_n, again.force_n)
    assert np.array_equal(got.force.pressure_kpa, again.pressure_kpa)

    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="effective modulus"):
            p.set_elastomer(bad)
    assert p.effective_modulus_mpa == 0.4, "a refused modulus changes nothing"
    with pytest.raises(ValueError, match="crop"):
        p.solve_force(zeros[:-1])
    p.set_elastomer(None)
    assert not p.has_force and p.effective_modulus_mpa is None
    assert p.predict(densetact.read_frame(cases[0]["frame"]), always=True).force is None
