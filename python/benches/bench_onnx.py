"""The whole predictor's ONNX file (`train onnx`) in ONNX Runtime (and OpenCV's DNN module) against
`predict` (the Python package, which equals `infer predict` bit for bit): the depth error on a
dataset split's frames and the time per frame of each, measured in one run on the same frames:

    python python/benches/bench_onnx.py --bundle B --onnx B.onnx --data D [--split test] [--repeats 30]
        [--baseline OLD.onnx ...] [--opencv] [--threads N]

`--baseline` names earlier exports of the same bundle (an older `train onnx`'s file) to check and
time beside `--onnx`: a change to the graph is measured before and after in one process, every
runtime's rows interleaved call by call, so that this machine's drift falls on all of them alike.
"""

import argparse
import os
import statistics
import time

import numpy as np
import onnxruntime as ort

import densetact

WARM_UP = 5


def interleaved_ms(rows, repeats):
    """Each row's time per call (ms), the rows called in turn `repeats` times after a warm-up;
    median [quartiles] per row."""
    times = {name: [] for name, _ in rows}
    for rep in range(WARM_UP + repeats):
        for name, f in rows:
            start = time.perf_counter()
            f()
            if rep >= WARM_UP:
                times[name].append((time.perf_counter() - start) * 1e3)
    out = {}
    for name, t in times.items():
        q = statistics.quantiles(t, n=4)
        out[name] = f"{statistics.median(t):.2f} [{q[0]:.2f}, {q[2]:.2f}]"
    return out


class Runner:
    """One ONNX file in one runtime: `run(frame)` gives its named outputs."""

    def __init__(self, runtime, path, threads):
        self.name = f"{runtime}, {path}"
        if runtime == "ONNX Runtime":
            so = ort.SessionOptions()
            so.intra_op_num_threads = threads
            s = ort.InferenceSession(path, so, providers=["CPUExecutionProvider"])
            names = [o.name for o in s.get_outputs()]
            self.run = lambda frame, names=names: dict(zip(names, s.run(names, {"frame": frame})))
            self.names = names
        else:
            import cv2  # only with --opencv

            net = cv2.dnn.readNetFromONNX(path)
            names = list(net.getUnconnectedOutLayersNames())

            def run(frame):
                net.setInput(frame, "frame")
                return dict(zip(names, net.forward(names)))

            self.run, self.names = run, names


def check(runner, predictor, frames):
    """The largest differences from `predict` over `frames`, and the frames the gate agrees on."""
    worst, worst_kpa, worst_n, agrees = 0.0, 0.0, 0.0, 0
    for frame in frames:
        want = predictor.predict(frame)
        out = runner.run(frame)
        worst = max(worst, float(np.abs(out["depth_mm"] - want.depth_mm).max()))
        if want.force is not None and "pressure_kpa" in out:
            worst_kpa = max(worst_kpa, float(np.abs(out["pressure_kpa"] - want.force.pressure_kpa).max()))
            worst_n = max(worst_n, float(np.abs(out["force_n"] - np.asarray(want.force.force_n)).max()))
        agrees += bool(np.asarray(out["contact"]).reshape(-1)[0]) == want.network_ran
    return worst, worst_kpa, worst_n, agrees


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", required=True)
    ap.add_argument("--onnx", required=True)
    ap.add_argument("--baseline", action="append", default=[], help="an earlier export to set beside --onnx")
    ap.add_argument("--opencv", action="store_true", help="run the files in OpenCV's DNN module too")
    ap.add_argument("--threads", type=int, default=os.cpu_count(), help="the runtimes' threads")
    ap.add_argument("--data", required=True, help="a dataset folder")
    ap.add_argument("--split", default="test")
    ap.add_argument("--repeats", type=int, default=30)
    args = ap.parse_args()
    p = densetact.Predictor(args.bundle)
    frames = [image for image, _, _ in densetact.Dataset(args.data, split=args.split)]
    runtimes = ["ONNX Runtime"] + (["OpenCV"] * args.opencv)
    if args.opencv:
        import cv2

        cv2.setNumThreads(args.threads)
        print(f"OpenCV {cv2.__version__}")
    runners = [Runner(rt, path, args.threads) for path in [*args.baseline, args.onnx] for rt in runtimes]
    print(f"ONNX Runtime {ort.__version__}, {args.threads} threads; {len(frames)} {args.split} frames")
    for r in runners:
        worst, worst_kpa, worst_n, agrees = check(r, p, frames)
        line = f"  {r.name}: largest |depth - predict| {worst:.3e} mm; gate agrees on {agrees}/{len(frames)}"
        if p.has_force and "pressure_kpa" in r.names:
            line += f"; |pressure - predict| {worst_kpa:.3e} kPa, |force - predict| {worst_n:.3e} N"
        print(line)
    pressed = [f for f in frames if p.predict(f).network_ran]
    frame = pressed[0] if pressed else frames[0]
    print(f"ms per frame (a frame with contact), {args.repeats} rounds interleaved, median [quartiles]:")
    rows = [("flex, densetact.Predictor.predict", lambda: p.predict(frame))]
    rows += [(r.name, lambda r=r: r.run(frame)) for r in runners]
    for name, t in interleaved_ms(rows, args.repeats).items():
        print(f"  {name:48} {t}")


if __name__ == "__main__":
    main()
