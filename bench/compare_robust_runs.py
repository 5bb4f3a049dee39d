#!/usr/bin/env python3
"""Compares a toro_offline run of a bag with wrong loop closures against the run of the clean bag
(bench/run_robust_offline.sh): final position RMSE of each against the clean file's optimum after
a rigid alignment, and how far the robot ever appeared apart in the two maps (robot_in_map of the
summaries: map_T_odom after every odometry message applied to that message's pose), also allowing
the clean run's map_T_odom up to 1 s of message time earlier or later, applied to the same odometry
pose (a correction that came a moment earlier or later is latency rather than a bend).

  compare_robust_runs.py OPTIMUM.g2o CLEAN_DIR OUTLIER_DIR      (prints one JSON object)
"""
import json
import sys

import numpy as np

SHIFT_SEC = 1.0


def positions(path):
    """Vertex positions of a g2o file (3D or 2D), in id order."""
    nodes = {}
    with open(path) as f:
        for line in f:
            p = line.split()
            if not p:
                continue
            if p[0] == "VERTEX_SE3:QUAT":
                nodes[int(p[1])] = [float(p[2]), float(p[3]), float(p[4])]
            elif p[0] == "VERTEX_SE2":
                nodes[int(p[1])] = [float(p[2]), float(p[3]), 0.0]
    return np.array([nodes[k] for k in sorted(nodes)])


def transforms(samples):
    """map_T_odom samples [t, x, y, z, qx, qy, qz, qw] as ({t: rotation matrix}, {t: translation})."""
    rotations, translations = {}, {}
    for t, x, y, z, qx, qy, qz, qw in samples:
        rotations[round(t, 6)] = np.array([
            [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
            [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
            [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]])
        translations[round(t, 6)] = np.array([x, y, z])
    return rotations, translations


def latency_tolerant_gap(common, clean_transforms, outliers, outlier_transforms):
    """The largest gap with the clean run's correction (map_T_odom) of any moment within SHIFT_SEC of
    message time applied to this run's odometry pose then: a right correction that came a moment
    earlier or later in one run (a finish at another moment) counts as latency here, not as a bend;
    a wrong loop closure that bends the map for longer still shows.  (Comparing positions at other
    moments instead would count the robot's own motion as a gap.)  None when a summary has no
    map_T_odom (written before 2026-12-06)."""
    clean_rotations, clean_translations = clean_transforms
    out_rotations, out_translations = outlier_transforms
    if not common or any(t not in clean_rotations or t not in out_rotations for t in common):
        return None
    times = np.array(common)
    clean_r = np.array([clean_rotations[t] for t in common])
    clean_t = np.array([clean_translations[t] for t in common])
    gap = 0.0
    for t in common:
        # The odometry pose's position at t, from this run's map position and correction.
        odom_position = out_rotations[t].T @ (outliers[t] - out_translations[t])
        lo, hi = np.searchsorted(times, t - SHIFT_SEC), np.searchsorted(times, t + SHIFT_SEC, side="right")
        shown = clean_r[lo:hi] @ odom_position + clean_t[lo:hi]
        gap = max(gap, float(np.min(np.linalg.norm(shown - outliers[t], axis=1))))
    return gap


def aligned_rmse(a, b):
    """RMSE of a against b after the rigid motion that best maps a onto b (Kabsch)."""
    n = min(len(a), len(b))
    a, b = a[:n], b[:n]
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return float(np.sqrt((((r @ (a - ca).T).T + cb - b) ** 2).sum(axis=1).mean()))


def main():
    optimum, clean_dir, outlier_dir = sys.argv[1:4]
    reference = positions(optimum)
    out = {}
    for name, d in (("clean", clean_dir), ("outliers", outlier_dir)):
        out[name + "_rmse_m"] = aligned_rmse(positions(d + "/corrected.g2o"), reference)
        with open(d + "/summary.json") as f:
            s = json.load(f)
        out[name + "_wall_sec"] = s["wall_sec"]
        out[name + "_down_weighted"] = s.get("loop_closures_down_weighted", 0)
        out[name + "_applied"] = s["loop_closures_applied"]
        out[name + "_trace"] = {round(t, 6): np.array([x, y, z]) for t, x, y, z in s["robot_in_map"]}
        out[name + "_transforms"] = transforms(s.get("map_T_odom", []))  # absent before 2026-12-06
    clean, outliers = out.pop("clean_trace"), out.pop("outliers_trace")
    clean_transforms, outlier_transforms = out.pop("clean_transforms"), out.pop("outliers_transforms")
    common = sorted(set(clean) & set(outliers))
    gaps = [float(np.linalg.norm(clean[t] - outliers[t])) for t in common]
    out["max_gap_m"] = max(gaps) if gaps else None
    out["max_gap_within_1s_m"] = latency_tolerant_gap(common, clean_transforms, outliers, outlier_transforms)
    out["samples"] = len(common)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
