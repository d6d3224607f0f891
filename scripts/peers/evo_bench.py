"""Time evo 1.38 on the same work as `stride bench eval`: load two TUM files, APE with SE(3)
alignment (t_max_diff 0.01 s) and RPE over 1 frame. Prints one JSON object.

Run with the python of a throwaway venv that has evo (never a project dependency):
    python evo_bench.py GT EST RUNS
"""
import json
import statistics
import sys
import time

from evo.core import metrics, sync
from evo.tools import file_interface


def main() -> None:
    gt_path, est_path, runs = sys.argv[1], sys.argv[2], int(sys.argv[3])
    load, ape_t, rpe_t = [], [], []
    ape_rmse = rpe_rmse = float("nan")
    for _ in range(runs):
        t0 = time.perf_counter()
        ref = file_interface.read_tum_trajectory_file(gt_path)
        est = file_interface.read_tum_trajectory_file(est_path)
        t1 = time.perf_counter()
        r, e = sync.associate_trajectories(ref, est, max_diff=0.01)
        e.align(r)
        ape = metrics.APE(metrics.PoseRelation.translation_part)
        ape.process_data((r, e))
        ape_rmse = ape.get_statistic(metrics.StatisticsType.rmse)
        t2 = time.perf_counter()
        r, e = sync.associate_trajectories(ref, est, max_diff=0.01)
        rpe = metrics.RPE(metrics.PoseRelation.translation_part, 1, metrics.Unit.frames)
        rpe.process_data((r, e))
        rpe_rmse = rpe.get_statistic(metrics.StatisticsType.rmse)
        t3 = time.perf_counter()
        load.append(t1 - t0)
        ape_t.append(t2 - t1)
        rpe_t.append(t3 - t2)
    print(json.dumps({
        "load_s": statistics.median(load),
        "ate_s": statistics.median(ape_t),
        "rpe_s": statistics.median(rpe_t),
        "ate_rmse": ape_rmse,
        "rpe_rmse": rpe_rmse,
        "runs": runs,
    }))


if __name__ == "__main__":
    main()
