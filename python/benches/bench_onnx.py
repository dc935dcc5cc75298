"""The whole predictor's ONNX file (`train onnx`) in ONNX Runtime against `predict` (the Python
package, which equals `infer predict` bit for bit): the depth error on a dataset split's frames
and the time per frame of each, measured in one run on the same frames:

    python python/benches/bench_onnx.py --bundle B --onnx B.onnx --data D [--split test] [--repeats 30]
"""

import argparse

import numpy as np
import onnxruntime as ort

import densetact
from bench_predict import timed_ms  # this folder is the script's, so on the path


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", required=True)
    ap.add_argument("--onnx", required=True)
    ap.add_argument("--data", required=True, help="a dataset folder")
    ap.add_argument("--split", default="test")
    ap.add_argument("--repeats", type=int, default=30)
    args = ap.parse_args()
    p = densetact.Predictor(args.bundle)
    s = ort.InferenceSession(args.onnx, providers=["CPUExecutionProvider"])
    frames = [image for image, _, _ in densetact.Dataset(args.data, split=args.split)]
    names = [o.name for o in s.get_outputs()]
    worst, worst_kpa, worst_n, gate_agrees, pressed = 0.0, 0.0, 0.0, 0, []
    for frame in frames:
        want = p.predict(frame)
        out = dict(zip(names, s.run(names, {"frame": frame})))
        depth, contact = out["depth_mm"], out["contact"]
        worst = max(worst, float(np.abs(depth - want.depth_mm).max()))
        if want.force is not None:
            worst_kpa = max(worst_kpa, float(np.abs(out["pressure_kpa"] - want.force.pressure_kpa).max()))
            worst_n = max(worst_n, float(np.abs(out["force_n"] - np.asarray(want.force.force_n)).max()))
        gate_agrees += bool(contact) == want.network_ran
        if want.network_ran:
            pressed.append(frame)
    print(f"ONNX Runtime {ort.__version__}, {args.onnx}: {len(frames)} {args.split} frames")
    print(f"  largest |depth - predict| {worst:.3e} mm; gate agrees on {gate_agrees}/{len(frames)}")
    if p.has_force:
        print(f"  largest |pressure - predict| {worst_kpa:.3e} kPa, |force - predict| {worst_n:.3e} N")
    frame = pressed[0] if pressed else frames[0]
    print(f"ms per frame (a frame with contact) over {args.repeats} runs, median [quartiles]:")
    rows = [
        ("ONNX Runtime, whole predictor", lambda: s.run(["depth_mm"], {"frame": frame})),
        ("flex, densetact.Predictor.predict", lambda: p.predict(frame)),
    ]
    for name, f in rows:
        print(f"  {name:36} {timed_ms(f, args.repeats)}")


if __name__ == "__main__":
    main()
