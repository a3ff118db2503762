"""Speed of ``Map.covisibility`` on a large map (~1000 keyframes) after one map change.

Between two map changes (a keyframe, new or culled points, a fusion) the system asks the
covisibility of some keyframes, several of them more than once (local-map tracking every frame, the
keyframe decision, fusion, culling, loop detection). The table gives the total time of one change
(a keyframe re-observes 20 points and loses 20, then ``Map.invalidate([its id])``) and ``Q`` queries
after it (``Q/2`` keyframes, each asked twice):

* ``rebuild``: the code before the incremental table: the whole observation table rebuilt from the
  keyframes' ``map_point_ids`` after every change, then one ``np.isin`` scan of it per query (the
  point index built after a few scans only cut the scans, not the rebuild);
* ``incremental``: ``Map.covisibility`` as it is now: the change costs O(its observations) (rows
  killed and appended, the covisibility of the keyframes sharing its points dropped), a query
  O(the rows of its points);
* ``full sync``: ``Map.invalidate()`` with no keyframe named (every keyframe compared with the
  table) and one query; ``compact``: one compaction of the table (amortised: once per 25 % rows).

The map is synthetic: ``K`` keyframes of 1000 keypoints, each making 150 points and re-observing
70 % of the points of the 6 keyframes before it. Usage::

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


def rebuild_table(mp: Map) -> tuple[np.ndarray, np.ndarray]:
    """The observation table ``(kf id, point id)`` rebuilt from every keyframe (the code before)."""
    kfs = list(mp.keyframes.values())
    has = [k.map_point_ids >= 0 for k in kfs]
    return (np.concatenate([np.full(int(h.sum()), k.id, np.int64) for k, h in zip(kfs, has)]),
            np.concatenate([k.map_point_ids[h] for k, h in zip(kfs, has)]))


def covisibility_scan(table: tuple[np.ndarray, np.ndarray], mp: Map, kf_id: int) -> dict[int, int]:
    """Covisibility by an ``np.isin`` scan of the whole table (the code before, and the reference)."""
    kf = mp.keyframes[kf_id]
    ids = kf.map_point_ids[kf.map_point_ids >= 0]
    kf_col, pt_col = table
    u, c = np.unique(kf_col[np.isin(pt_col, ids)], return_counts=True)
    out = {int(a): int(b) for a, b in zip(u, c)}
    out.pop(kf_id, None)
    return out


def change(mp: Map, rng: np.random.Generator) -> list[int]:
    """One map change: a random keyframe drops 20 observations and re-observes 20 other points."""
    kid = int(rng.choice(mp.keyframe_ids()))
    kf = mp.keyframes[kid]
    has = np.flatnonzero(kf.map_point_ids >= 0)
    kf.map_point_ids[rng.choice(has, 20, replace=False)] = -1
    free = np.flatnonzero(kf.map_point_ids < 0)
    new = np.setdiff1d(mp.point_ids(), kf.map_point_ids)
    kf.map_point_ids[rng.choice(free, 20, replace=False)] = rng.choice(new, 20, replace=False)
    return [kid]


def _total_ms(fn, mp: Map, queries: list[int], repeats: int, rng: np.random.Generator) -> float:
    """Median over ``repeats`` of: one map change (untimed edit, timed ``invalidate``), then ``fn(queries)``."""
    out = []
    for _ in range(repeats):
        kids = change(mp, rng)
        t0 = time.perf_counter()
        mp.invalidate(kids)
        fn(queries)
        out.append(1e3 * (time.perf_counter() - t0))
    return float(np.median(out))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keyframes", type=int, nargs="+", default=[250, 500, 1000], help="map sizes (keyframes)")
    ap.add_argument("--queries", type=int, nargs="+", default=[2, 10, 40, 160], help="queries after a change (Q)")
    ap.add_argument("--repeats", type=int, default=3, help="repeats per figure, median (default 3)")
    args = ap.parse_args()
    print(f"{'keyframes':>9} {'observations':>12} {'full sync ms':>12} {'compact ms':>10} {'Q':>4} "
          f"{'rebuild ms':>10} {'incremental ms':>14} {'rebuild/incremental':>19}")
    for n_kf in args.keyframes:
        mp = build_map(n_kf)
        rng = np.random.default_rng(1)
        ids = mp.keyframe_ids()
        for _ in range(3):  # same answers as the scan, also after changes, before timing anything
            mp.invalidate(change(mp, rng))
            table = rebuild_table(mp)
            for q in rng.choice(ids, 20, replace=False):
                assert mp.covisibility(int(q)) == covisibility_scan(table, mp, int(q)), "covisibility differs from the scan"
        t0 = time.perf_counter()
        mp.invalidate()
        mp.covisibility(ids[0])
        full = 1e3 * (time.perf_counter() - t0)
        t0 = time.perf_counter()
        mp._compact()
        compact = 1e3 * (time.perf_counter() - t0)
        n_obs = len(mp._table()[0])
        for n_q in args.queries:
            kfs = [int(k) for k in rng.choice(ids, max(n_q // 2, 1), replace=False)]
            queries = kfs + kfs

            def before(qs):
                table = rebuild_table(mp)
                for q in qs:
                    covisibility_scan(table, mp, q)

            def after(qs):
                for q in qs:
                    mp.covisibility(q)

            b = _total_ms(before, mp, queries, args.repeats, rng)
            a = _total_ms(after, mp, queries, args.repeats, rng)
            print(f"{n_kf:>9} {n_obs:>12} {full:>12.1f} {compact:>10.1f} {len(queries):>4} "
                  f"{b:>10.1f} {a:>14.2f} {b / a:>19.1f}", flush=True)


if __name__ == "__main__":
    main()
