"""The whole predictor's ONNX file (`train onnx`) in ONNX Runtime against `infer predict`: the
frame cut by the crop rule the metadata states, depth within 1e-3 mm, nothing else from the
bundle."""

import json

import numpy as np
import pytest

import densetact
from conftest import peer

ort = peer("onnxruntime")


def test_onnx_runtime_gives_infer_predicts_depth(root, bundle, cases):
    predictor = densetact.Predictor(bundle)
    session = ort.InferenceSession(str(root / "predictor.onnx"), providers=["CPUExecutionProvider"])
    crop = json.loads(session.get_modelmeta().custom_metadata_map["densetact.crop"])
    (x0, y0), n = crop["origin_px"], crop["size_px"]
    assert [i.name for i in session.get_inputs()] == ["frame"]
    ran = 0
    for case in cases:
        frame = densetact.read_frame(case["frame"])
        if frame.shape[:2] != (n, n):
            assert list(frame.shape[1::-1]) == crop["frame_px"]
            frame = frame[y0 : y0 + n, x0 : x0 + n]
        depth, contact = session.run(["depth_mm", "contact"], {"frame": np.ascontiguousarray(frame)})
        expected = np.load(case["depth_npy"])
        assert depth.dtype == np.float32 and depth.shape == expected.shape
        assert np.abs(depth - expected).max() <= 1e-3, case["frame"]
        assert bool(contact) == predictor.predict(frame).network_ran, case["frame"]
        ran += bool(contact)
    assert ran > 0, "some frames pressed the gel"
