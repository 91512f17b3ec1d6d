#!/usr/bin/env python3
"""The baseline of the atlas-load benchmark (docs/atlas.md "Performance"): nibabel reading the
same NIfTI files an atlas holds, into arrays of their stored type, as a plain script would.

    python3 -m venv /tmp/nibenv && /tmp/nibenv/bin/pip install nibabel numpy
    /tmp/nibenv/bin/python benches/atlas_load/nibabel_load.py ATLAS_DIR [--runs 7]

Prints the median and best wall time of reading atlas.toml's two volumes (ct, labels), one after
the other, every voxel decompressed.
"""
import argparse
import pathlib
import statistics
import time
import tomllib

import nibabel as nib
import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("atlas")
    ap.add_argument("--runs", type=int, default=7)
    a = ap.parse_args()
    d = pathlib.Path(a.atlas)
    manifest = tomllib.loads((d / "atlas.toml").read_text())
    files = [d / manifest["volumes"]["ct"], d / manifest["volumes"]["labels"]]
    times = []
    for _ in range(a.runs):
        t = time.perf_counter()
        voxels = 0
        for f in files:
            arr = np.asanyarray(nib.load(f).dataobj)
            voxels += arr.size
        times.append(time.perf_counter() - t)
    print(f"nibabel: {voxels} voxels in 2 files, median {statistics.median(times):.3f} s, best {min(times):.3f} s ({a.runs} runs)")


if __name__ == "__main__":
    main()
