"""Speed of ``Map.covisibility`` on a large map (~1000 keyframes), before/after the point index.

Between two map changes (a keyframe, new or culled points, a fusion: every change calls
``Map.invalidate``) the system asks the covisibility of some keyframes, several of them more
than once (local-map tracking every frame, the keyframe decision, fusion, culling). The table
gives the total time of ``Q`` such queries after one change (``Q/2`` keyframes, each asked twice):

* ``before``: the previous implementation, an ``np.isin`` scan of the whole observation table
  per query, no cache;
* ``after``: ``Map.covisibility`` as it is now: a cache per keyframe, the first
  ``Map.INDEX_AFTER_SCANS`` misses answered by a scan, later ones by the point index (CSR,
  built once by a counting sort);
* ``index``: the cost of building the point index once; ``scan``: one scan.

Both include the rebuild of the observation table after the change (the same for both; the
``table`` column). The map is synthetic: ``K`` keyframes of 1000 keypoints, each making 150
points and re-observing 70 % of the points of the 6 keyframes before it. Usage::

    PYTHONPATH=. python benchmarks/covisibility_speed.py                 # K = 250, 500, 1000
    PYTHONPATH=. python benchmarks/covisibility_speed.py --keyframes 1000 --repeats 5

(``PYTHONPATH=.`` so that a checkout's package is imported, not an installed one.)
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from dynslam_lab.slam.frame import KeyFrame
from dynslam_lab.slam.map import Map


def build_map(n_kf: int, n_kp: int = 1000, new: int = 150, window: int = 6, seed: int = 0) -> Map:
    """A map of ``n_kf`` keyframes; keyframe i makes ``new`` points and observes those of the
    ``window`` keyframes before it (each point is seen by ``window + 1`` keyframes at most)."""
    rng = np.random.default_rng(seed)
    mp = Map()
    made: list[np.ndarray] = []
    for i in range(n_kf):  # building the fixture, not timed
        kid = mp.new_keyframe_id()
        kf = KeyFrame(id=kid, frame_index=i, timestamp=float(i), _T_w_c=np.eye(4), uv=rng.uniform(0, 640, (n_kp, 2)),
                      descriptors=np.zeros((n_kp, 32), np.uint8), octave=rng.integers(0, 8, n_kp),
                      angle=np.zeros(n_kp), points_c=np.zeros((n_kp, 3)), map_point_ids=np.full(n_kp, -1, np.int64),
                      static=np.ones(n_kp, bool), parent_id=kid - 1)
        old = np.concatenate(made[-window:]) if made else np.zeros(0, np.int64)
        old = old[rng.random(len(old)) < 0.7]  # not every old point is re-observed
        slots = rng.permutation(n_kp)
        kf.map_point_ids[slots[: len(old)]] = old[: n_kp - new]
        mp.add_keyframe(kf)
        free = slots[len(old): len(old) + new]
        made.append(mp.add_points(rng.normal(0, 1, (len(free), 3)) + [0, 0, 3], np.zeros((len(free), 32), np.uint8), kf, free))
    return mp


def covisibility_scan(mp: Map, kf_id: int) -> dict[int, int]:
    """The previous ``Map.covisibility``: an ``np.isin`` scan of the whole observation table."""
    kf = mp.keyframes[kf_id]
    ids = kf.map_point_ids[kf.map_point_ids >= 0]
    kf_col, pt_col = mp._table()[:2]
    u, c = np.unique(kf_col[np.isin(pt_col, ids)], return_counts=True)
    out = {int(a): int(b) for a, b in zip(u, c)}
    out.pop(kf_id, None)
    return out


def _total_ms(fn, mp: Map, queries: list[int], repeats: int) -> float:
    """Median over ``repeats`` of: one map change, then ``fn`` on every query."""
    out = []
    for _ in range(repeats):
        mp.invalidate()
        t0 = time.perf_counter()
        for q in queries:
            fn(q)
        out.append(1e3 * (time.perf_counter() - t0))
    return float(np.median(out))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keyframes", type=int, nargs="+", default=[250, 500, 1000], help="map sizes (keyframes)")
    ap.add_argument("--queries", type=int, nargs="+", default=[2, 10, 40, 160], help="queries after a change (Q)")
    ap.add_argument("--repeats", type=int, default=3, help="repeats per figure, median (default 3)")
    args = ap.parse_args()
    print(f"{'keyframes':>9} {'observations':>12} {'table ms':>8} {'scan ms':>7} {'index ms':>8} {'Q':>4} "
          f"{'before ms':>9} {'after ms':>8} {'before/after':>12}")
    for n_kf in args.keyframes:
        mp = build_map(n_kf)
        rng = np.random.default_rng(1)
        ids = mp.keyframe_ids()
        for q in rng.choice(ids, 20, replace=False):  # same answers before timing anything
            assert mp.covisibility(int(q)) == covisibility_scan(mp, int(q)), "covisibility differs from the scan"
        table = _total_ms(lambda q: mp._table(), mp, [0], args.repeats)
        mp._table()
        t0 = time.perf_counter()
        for q in ids[:20]:
            covisibility_scan(mp, q)
        scan = 1e3 * (time.perf_counter() - t0) / 20
        t0 = time.perf_counter()
        for _ in range(5):
            mp._pt_index = None
            mp._point_index()
        index = 1e3 * (time.perf_counter() - t0) / 5
        n_obs = len(mp._table()[0])
        for n_q in args.queries:
            kfs = [int(k) for k in rng.choice(ids, max(n_q // 2, 1), replace=False)]
            queries = kfs + kfs
            before = _total_ms(lambda q: covisibility_scan(mp, q), mp, queries, args.repeats)
            after = _total_ms(mp.covisibility, mp, queries, args.repeats)
            print(f"{n_kf:>9} {n_obs:>12} {table:>8.1f} {scan:>7.2f} {index:>8.1f} {len(queries):>4} "
                  f"{before:>9.1f} {after:>8.1f} {before / after:>12.2f}", flush=True)


if __name__ == "__main__":
    main()
