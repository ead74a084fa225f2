#!/bin/bash
# A GPU machine without a package registry, checked in one run (docs/guides/devices.md).
#
#   bash bench/tools/device_session.sh prepare [BONSAI_DIR [NDRF_STUDENT LEGO_DIR]]   # on a connected machine
#   bash bench/tools/device_session.sh run      # on the GPU machine, as root, with .gpu/ copied beside the tree
#
# prepare: fills .gpu/ (git-ignored, at most 60 MiB): Python 3.12 wheels of what the GPU
# image lacks, device_check's reference images (made with PoCL), the bonsai LLFF folder
# (bench.tools.public_scenes) and, given, a baked NDRF student with its dataset's first 5
# test frames (lego's transforms_test.json, cut).
# run: registers the vendor's OpenCL driver (/etc/OpenCL/vendors), makes clrender
# importable from the tree (its entry points, kernels/ as clrender.kernels), then
# device_check, the kernel = reference tests on the GPU's platform (the GPU variants
# included), a `cpu-long` bonsai model trained with torch on CUDA, its stages against their
# bounds at 800x800 and 1920x1080 and every GPU variant paired against the default
# (bench.speed.ngprt_variants), the NDRF student's stages at both sizes, and the
# random-model kernel tables. Logs and results under $OUT (results.tgz: the JSON).
set -u
cd "$(dirname "$0")/../.."
G=.gpu
WHEELS="pyopencl==2026.1.4 pytools==2026.1.1 platformdirs==4.14.9 siphash24==1.9
        embreex==4.4.0.post1 trimesh==5.2.0 fast-simplification==0.2.0 filelock==4.3.2"

prepare() {
    local bonsai=${1:-} student=${2:-} lego=${3:-}
    grep -qx "/$G/" .git/info/exclude 2>/dev/null || echo "/$G/" >> .git/info/exclude
    mkdir -p $G/whl $G/devcheck
    for w in $WHEELS; do
        python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
            --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 \
            --platform manylinux2014_x86_64 -d $G/whl "$w" || exit 1
    done
    # Only the images travel: the example models are remade there (deterministic; md5 printed).
    local tmp; tmp=$(mktemp -d)
    .venv/bin/python -m bench.tools.device_check --make-reference "$tmp" || exit 1
    cp "$tmp"/reference.npz "$tmp"/reference.json "$tmp"/ndrf.npz $G/devcheck/ && rm -rf "$tmp"
    if [ -n "$bonsai" ]; then
        mkdir -p $G/bonsai && cp -rL "$bonsai"/images "$bonsai"/poses_bounds.npy $G/bonsai/
    fi
    if [ -n "$student" ]; then
        mkdir -p $G/ndrf/lego && cp "$student" $G/ndrf/student.npz || exit 1
        .venv/bin/python - "$lego" $G/ndrf/lego <<'EOF' || exit 1
import json, shutil, sys
from pathlib import Path
src, dst = Path(sys.argv[1]), Path(sys.argv[2])
test = json.loads((src / "transforms_test.json").read_text())
test["frames"] = test["frames"][:5]            # the cameras timed there
for frame in test["frames"]:
    name = frame["file_path"] + ("" if Path(frame["file_path"]).suffix else ".png")
    (dst / name).parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(src / name, dst / name)
(dst / "transforms_test.json").write_text(json.dumps(test, indent=1))
EOF
    fi
    du -sh --apparent-size $G
    local kib; kib=$(du -sk --apparent-size $G | cut -f1)
    [ "$kib" -le $((60 * 1024)) ] || { echo ".gpu/ is over 60 MiB: leave something out" >&2; exit 1; }
}

run() {
    local T0 R=/tmp/results; T0=$(date +%s); mkdir -p $R "$OUT"
    exec > >(tee -a "$OUT/run.log") 2>&1
    step() { echo; echo "=== $(( $(date +%s) - T0 )) s: $*"; }
    pack() { tar czf "$OUT/results.tgz" -C $R . 2>/dev/null; }

    step setup
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
        --target /tmp/site $G/whl/*.whl || exit 1
    local d=/tmp/site/clrender-0.1.0.dist-info; mkdir -p $d
    printf 'Metadata-Version: 2.1\nName: clrender\nVersion: 0.1.0\n' > $d/METADATA
    python3 - > $d/entry_points.txt <<'EOF'
import tomllib
groups = tomllib.load(open("pyproject.toml", "rb"))["project"]["entry-points"]
for group, entries in groups.items():
    print(f"[{group}]", *(f"{k} = {v}" for k, v in entries.items()), "", sep="\n")
EOF
    ln -sfn ../kernels clrender/kernels
    export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 TQDM_MININTERVAL=20 CLRENDER_CACHE=/tmp/cache
    nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv
    python3 -c "import torch, numpy, pyopencl; print(torch.__version__, numpy.__version__, pyopencl.VERSION_TEXT)"
    local lib; lib=$(ldconfig -p | awk '/libnvidia-opencl\.so\.1/{print $NF; exit}')
    [ -n "$lib" ] || lib=$(find /usr/local/nvidia /usr/lib /usr/lib64 -name 'libnvidia-opencl.so*' \
        2>/dev/null | head -1)
    echo "NVIDIA OpenCL library: ${lib:-none found}"
    mkdir -p /etc/OpenCL/vendors && [ -n "$lib" ] && echo "$lib" > /etc/OpenCL/vendors/nvidia.icd
    timeout 60 python3 -m clrender.cli info

    step device_check
    python3 -c "from pathlib import Path; from bench.tools.device_check import make_models; make_models(Path('$G/devcheck'))"
    md5sum $G/devcheck/*.npz
    timeout 120 python3 -m bench.tools.device_check --reference $G/devcheck --out $R --repeats 5
    pack

    step "kernel = reference tests on the GPU's platform"
    CLRENDER_TEST_PLATFORMS="nvidia=NVIDIA CUDA" timeout 150 python3 -m pytest -n 6 -q \
        -p no:cacheprovider -m "not oclgrind" -k "not pocl and not intel" --durations=10 -rfEs \
        --junitxml=$R/kernel_tests.xml tests/test_render_cl.py tests/test_render_tuning.py \
        tests/test_render_fast.py \
        tests/test_ngprt_unbounded.py tests/test_ngprt_holes.py tests/test_ngprt_lattice.py \
        tests/test_ndrf_raster.py tests/test_ndrf_shader.py tests/test_camera.py \
        tests/test_baked_fuzz.py tests/test_ndrf_baked_fuzz.py tests/test_frame_blocking.py
    pack

    if [ -d $G/bonsai ]; then
        step "bonsai: cpu-long, torch engine on CUDA"
        time timeout 240 python3 -m clrender.cli train $G/bonsai --downscale 2 --preset cpu-long \
            --engine torch --torch-device cuda --out /tmp/bonsai > /tmp/train.log 2>&1
        tail -n 2 /tmp/bonsai/log.jsonl
        timeout 60 python3 -m clrender.cli bake /tmp/bonsai --out /tmp/bonsai.npz
        timeout 60 python3 -m clrender.cli eval /tmp/bonsai.npz $G/bonsai --downscale 2 | tee $R/bonsai_eval.json
        timeout 150 python3 -m bench.speed.ngprt_variants --model /tmp/bonsai.npz --data $G/bonsai \
            --downscale 2 --sizes 800x800 1920x1080 --views 5 --repeats 5 --out $R
        pack
    fi

    if [ -f $G/ndrf/student.npz ]; then
        step "NDRF student: stages at 800x800 and 1920x1080"
        timeout 90 python3 -m bench.speed.ndrf_kernels --model $G/ndrf/student.npz \
            --data $G/ndrf/lego --repeats 5 --out $R
        pack
    fi

    step "random models: NGP-RT and NDRF kernel tables"
    timeout 60 python3 -m bench.speed.ngprt_kernels --size 800 --repeats 5 --variant separate-v --out $R
    timeout 60 python3 -m bench.speed.ndrf_kernels --repeats 5 --out $R
    pack
    step done
}

case "${1:-}" in
    prepare) shift; prepare "$@" ;;
    run) run ;;
    *) echo "usage: bash bench/tools/device_session.sh prepare [BONSAI_DIR [NDRF_STUDENT LEGO_DIR]] | run" >&2
       exit 2 ;;
esac
