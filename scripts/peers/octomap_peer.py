"""OctoMap on the clouds stride's elevation mappers get, for `stride bench map --octomap`.

    python octomap_peer.py map IN OUT RES [RES ...]   clouds in IN, grids and timings to OUT
    python octomap_peer.py voxels IN OUT RES          a hand-made octree (for the tests)

IN holds `frames.json` ({"grid": {origin_x, origin_y, resolution, rows, cols}, "frames":
[{"origin": [x, y, z], "points": n}, ...]}) and `points.f32` (every frame's points in the
world frame, z up, m: x y z little-endian float32, frame after frame). Each frame is
inserted with ray casting (free space along every ray) and OctoMap's default sensor model,
as OctoMap users run it: `insertPointCloud(points, origin)` with no range limit and no
discretisation. For `voxels`, IN is a JSON file {"grid": ..., "nodes": [[x, y, z,
occupied], ...]} of single node updates.

The 2.5-D conversion: every occupied leaf covers the grid cells whose centres lie inside its
square footprint; a cell's height is the centre height of the highest occupied voxel (at the
tree's resolution: a pruned leaf counts as its top layer) over it, NaN where none. OUT gets `elevation_<RES in mm>mm.f32` (rows x cols float32, row-major,
row 0 at origin_y) per resolution and `result.json` (insert ms per frame, memory, leaves).

Run with the python of a throwaway venv that has pyoctomap (never a project dependency).
"""
import json
import math
import os
import sys
import time

import numpy as np
import pyoctomap


def to_grid(tree, grid):
    """The highest occupied voxel over each cell's centre (its centre height), NaN elsewhere."""
    voxel = tree.getResolution()
    rows, cols, res = grid["rows"], grid["cols"], grid["resolution"]
    x0, y0 = grid["origin_x"], grid["origin_y"]
    out = np.full((rows, cols), np.nan, dtype=np.float64)
    for leaf in tree.begin_leafs():
        if not tree.isNodeOccupied(leaf):
            continue
        x, y, z = leaf.getCoordinate()
        half = leaf.getSize() / 2.0
        # Cells whose centres lie in [x - half, x + half) x [y - half, y + half).
        c0 = max(0, math.ceil((x - half - x0) / res - 1e-9))
        c1 = min(cols, math.ceil((x + half - x0) / res - 1e-9))
        r0 = max(0, math.ceil((y - half - y0) / res - 1e-9))
        r1 = min(rows, math.ceil((y + half - y0) / res - 1e-9))
        if c0 >= c1 or r0 >= r1:
            continue
        block = out[r0:r1, c0:c1]
        np.fmax(block, z + half - voxel / 2.0, out=block)
    return out.astype(np.float32)


def write_grid(path, grid):
    tmp = path + ".tmp"
    grid.astype("<f4").tofile(tmp)
    os.replace(tmp, path)


def run_map(src, dst, resolutions):
    with open(os.path.join(src, "frames.json")) as f:
        spec = json.load(f)
    points = np.fromfile(os.path.join(src, "points.f32"), dtype="<f4").reshape(-1, 3)
    result = {"octomap": "pyoctomap " + getattr(pyoctomap, "__version__", "?"), "runs": {}}
    for res in resolutions:
        tree = pyoctomap.OcTree(res)
        insert_ms, start = [], 0
        for fr in spec["frames"]:
            n = fr["points"]
            cloud = points[start:start + n].astype(np.float64)
            start += n
            t0 = time.perf_counter()
            tree.insertPointCloud(cloud, np.array(fr["origin"], dtype=np.float64))
            insert_ms.append((time.perf_counter() - t0) * 1e3)
        t0 = time.perf_counter()
        grid = to_grid(tree, spec["grid"])
        convert_ms = (time.perf_counter() - t0) * 1e3
        name = "elevation_%dmm.f32" % round(res * 1000)
        write_grid(os.path.join(dst, name), grid)
        result["runs"][name] = {
            "resolution_m": res,
            "insert_ms": insert_ms,
            "convert_ms": convert_ms,
            "memory_bytes": tree.memoryUsage(),
            "leaf_nodes": tree.getNumLeafNodes(),
        }
    with open(os.path.join(dst, "result.json"), "w") as f:
        json.dump(result, f)


def run_voxels(src, dst, res):
    with open(src) as f:
        updates = json.load(f)
    grid = updates["grid"]
    tree = pyoctomap.OcTree(res)
    for x, y, z, occupied in updates["nodes"]:
        tree.updateNode(np.array([x, y, z], dtype=np.float64), bool(occupied))
    tree.updateInnerOccupancy()
    write_grid(os.path.join(dst, "elevation.f32"), to_grid(tree, grid))


def main():
    mode = sys.argv[1]
    if mode == "map":
        run_map(sys.argv[2], sys.argv[3], [float(r) for r in sys.argv[4:]])
    elif mode == "voxels":
        run_voxels(sys.argv[2], sys.argv[3], float(sys.argv[4]))
    else:
        sys.exit("unknown mode %r (map or voxels)" % mode)


if __name__ == "__main__":
    main()
