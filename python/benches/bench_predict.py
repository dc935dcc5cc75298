"""Milliseconds per frame through the Python package, to set beside `infer bench`'s figures for
the same bundle and frame (run both back to back on the same machine; BENCHMARKS.md):

    python python/benches/bench_predict.py --bundle B --image F [--repeats 50]
    cargo run --release -p infer -- bench --bundle B --image F --repeats 50

`infer bench`'s "end to end" decodes the frame's bytes, runs the network and makes the contact
point cloud; `predict(path, always=True)` here does that and also reads the file and hands the
maps to NumPy. `predict(array)` starts from pixels already in memory.
"""

import argparse
import statistics
import time

import densetact


def timed_ms(f, repeats):
    f()  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        f()
        times.append((time.perf_counter() - start) * 1e3)
    q = statistics.quantiles(times, n=4)
    return f"{statistics.median(times):.2f} [{q[0]:.2f}, {q[2]:.2f}]"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", required=True)
    ap.add_argument("--image", required=True, help="a frame with contact (PNG or JPEG)")
    ap.add_argument("--repeats", type=int, default=50)
    args = ap.parse_args()
    p = densetact.Predictor(args.bundle)
    frame = densetact.read_frame(args.image)
    print(f"{p!r}; ms per frame over {args.repeats} frames, median [quartiles]:")
    print(f"  predict(path, always=True)   {timed_ms(lambda: p.predict(args.image, always=True), args.repeats)}")
    print(f"  predict(array, always=True)  {timed_ms(lambda: p.predict(frame, always=True), args.repeats)}")
    print(f"  read_frame(path)             {timed_ms(lambda: densetact.read_frame(args.image), args.repeats)}")


if __name__ == "__main__":
    main()
