"""Print evo's statistics for one APE or RPE configuration as JSON, for the agreement tests.

    python evo_stats.py ape GT EST ALIGN T_MAX_DIFF            (ALIGN: none|se3|sim3|origin)
    python evo_stats.py rpe GT EST ALIGN T_MAX_DIFF DELTA UNIT ALL_PAIRS   (UNIT: f|m)

Run with the python of a throwaway venv that has evo 1.38 (never a project dependency).
"""
import json
import sys

from evo.core import metrics, sync
from evo.tools import file_interface


def main() -> None:
    kind, gt_path, est_path, align, t_max_diff = sys.argv[1:6]
    ref = file_interface.read_tum_trajectory_file(gt_path)
    est = file_interface.read_tum_trajectory_file(est_path)
    ref, est = sync.associate_trajectories(ref, est, max_diff=float(t_max_diff))
    if align in ("se3", "sim3"):
        est.align(ref, correct_scale=(align == "sim3"))
    elif align == "origin":
        est.align_origin(ref)
    out = {}
    if kind == "ape":
        relations = {"": metrics.PoseRelation.translation_part,
                     "rot_deg_": metrics.PoseRelation.rotation_angle_deg}
        for prefix, rel in relations.items():
            m = metrics.APE(rel)
            m.process_data((ref, est))
            for k, v in m.get_all_statistics().items():
                out[prefix + k] = float(v)
            out["count"] = int(len(m.error))
    else:
        delta, unit, all_pairs = float(sys.argv[6]), sys.argv[7], sys.argv[8] == "1"
        unit = {"f": metrics.Unit.frames, "m": metrics.Unit.meters}[unit]
        relations = {"": metrics.PoseRelation.translation_part,
                     "rot_deg_": metrics.PoseRelation.rotation_angle_deg,
                     "rot_chordal_": metrics.PoseRelation.rotation_part}
        for prefix, rel in relations.items():
            m = metrics.RPE(rel, delta, unit, all_pairs=all_pairs)
            m.process_data((ref, est))
            for k, v in m.get_all_statistics().items():
                out[prefix + k] = float(v)
            out["count"] = int(len(m.error))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
