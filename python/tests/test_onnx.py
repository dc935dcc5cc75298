"""The whole predictor's ONNX file (`train onnx`) against `infer predict`, in ONNX Runtime and in
OpenCV's DNN module: the frame cut by the crop rule the metadata states, depth within 1e-3 mm,
nothing else from the bundle."""

import json

import numpy as np

import densetact
from conftest import peer

ort = peer("onnxruntime")


def cut(frame, crop):
    """A camera frame cut to the crop the metadata states (a crop-sized frame as it is)."""
    (x0, y0), n = crop["origin_px"], crop["size_px"]
    if frame.shape[:2] != (n, n):
        assert list(frame.shape[1::-1]) == crop["frame_px"]
        frame = frame[y0 : y0 + n, x0 : x0 + n]
    return np.ascontiguousarray(frame)


def cropped(cases, crop):
    """Each case's frame, cut, with its expected depth."""
    for case in cases:
        yield case, cut(densetact.read_frame(case["frame"]), crop), np.load(case["depth_npy"])


def test_onnx_runtime_gives_infer_predicts_depth(root, bundle, cases):
    predictor = densetact.Predictor(bundle)
    session = ort.InferenceSession(str(root / "predictor.onnx"), providers=["CPUExecutionProvider"])
    crop = json.loads(session.get_modelmeta().custom_metadata_map["densetact.crop"])
    assert [i.name for i in session.get_inputs()] == ["frame"]
    ran = 0
    for case, frame, expected in cropped(cases, crop):
        depth, contact = session.run(["depth_mm", "contact"], {"frame": frame})
        assert depth.dtype == np.float32 and depth.shape == expected.shape
        assert np.abs(depth - expected).max() <= 1e-3, case["frame"]
        assert bool(contact) == predictor.predict(frame).network_ran, case["frame"]
        ran += bool(contact)
    assert ran > 0, "some frames pressed the gel"


def test_opencv_gives_infer_predicts_depth(root, session, cases):
    """OpenCV's DNN module runs the same file (its importer wants every attribute on the wire, a
    scatter's indices no longer than its data, and `Abs` on floats only), both of the gate's
    branches."""
    cv2 = peer("cv2")
    crop = json.loads(
        ort.InferenceSession(str(root / "predictor.onnx"), providers=["CPUExecutionProvider"])
        .get_modelmeta()
        .custom_metadata_map["densetact.crop"]
    )
    net = cv2.dnn.readNetFromONNX(str(root / "predictor.onnx"))
    ran = 0
    for case, frame, expected in cropped(cases, crop):
        net.setInput(frame, "frame")
        depth, contact = net.forward(["depth_mm", "contact"])
        depth = np.asarray(depth)
        assert depth.dtype == np.float32 and depth.shape == expected.shape
        assert np.abs(depth - expected).max() <= 1e-3, case["frame"]
        ran += bool(np.asarray(contact).reshape(()))
    assert ran > 0, "some frames pressed the gel"
    # The untouched gel: the gate keeps the network from running, and the depth is zero.
    net.setInput(cut(densetact.read_frame(session / "reference.png"), crop), "frame")
    depth, contact = net.forward(["depth_mm", "contact"])
    n = crop["size_px"]
    assert not bool(np.asarray(contact).reshape(()))
    assert np.asarray(depth).shape == (n, n) and not np.asarray(depth).any()
