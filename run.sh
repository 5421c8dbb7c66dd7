#!/usr/bin/env bash
# usv_predictor: the two commands of the README, on a fresh Debian 12 / Python 3.11 machine.
#
#   ./run.sh demo          set up .venv, then run the demo (bags and reports land in out/)
#   ./run.sh test [ARGS]   set up .venv, then run the whole test suite (ARGS go to pytest)
#   ./run.sh setup         only set up .venv
#
# Set-up: a virtualenv in .venv with the pinned requirements.txt (the ROS 2 Jazzy Python wheels
# replace a ROS installation; nothing from apt but python3-venv), then the package itself as an
# editable install. It is skipped when .venv's stamp records the same hash of requirements.txt,
# the packaging files, the interpreter and the top-level packages, so the second run is fast.
# Override the interpreter with PYTHON=/path/to/python3.11.
set -euo pipefail

REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
VENV="$REPO/.venv"
STAMP="$VENV/.usv_predictor_setup.sha256"
PYTHON_BIN=${PYTHON:-python3}

say() { echo "run.sh: $*" >&2; }
die() { say "error: $*"; exit 1; }

usage() {
    sed -n '2,6p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'
}

check_python() {
    command -v "$PYTHON_BIN" >/dev/null 2>&1 ||
        die "$PYTHON_BIN not found. Install Python 3.11 (Debian 12: apt-get install python3 python3-venv)"
    "$PYTHON_BIN" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' ||
        die "Python 3.11 is required (the pinned ROS 2 Jazzy and torch wheels are built for it);" \
            "$PYTHON_BIN is $("$PYTHON_BIN" --version 2>&1). Set PYTHON=/path/to/python3.11"
}

# Debian splits ensurepip (which venv needs) into python3-venv; install it when we may.
ensure_venv_module() {
    "$PYTHON_BIN" -c 'import ensurepip, venv' >/dev/null 2>&1 && return 0
    if [[ $(id -u) -eq 0 ]] && command -v apt-get >/dev/null 2>&1; then
        say "python3-venv (ensurepip) is missing: installing it with apt-get"
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq python3-venv >/dev/null ||
            die "apt-get install python3-venv failed"
        "$PYTHON_BIN" -c 'import ensurepip, venv' >/dev/null 2>&1 && return 0
    fi
    die "Python's venv/ensurepip module is missing. Install it, then run again: sudo apt-get install python3-venv"
}

venv_works() {
    [[ -x "$VENV/bin/python" ]] && "$VENV/bin/python" -m pip --version >/dev/null 2>&1
}

make_venv() {
    venv_works && return 0
    if [[ -e "$VENV" ]]; then
        say "$VENV is broken or incomplete: recreating it"
        rm -rf "$VENV"
    fi
    ensure_venv_module
    say "creating the virtualenv $VENV"
    "$PYTHON_BIN" -m venv "$VENV" || die "python3 -m venv $VENV failed"
}

# Everything that decides what pip installs; a change re-runs the set-up.
setup_hash() {
    (
        cd "$REPO"
        cat requirements.txt setup.py setup.cfg package.xml run.sh
        "$VENV/bin/python" -VV
        ls -d -- */__init__.py 2>/dev/null || true  # new top-level packages need a new editable install
    ) | sha256sum | cut -d' ' -f1
}

# pip, with this machine's harmless "Location ... is ignored" noise about missing index folders removed.
pip_install() {
    local statuses
    set +e
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check "$@" 2>&1 |
        grep -v -e "is ignored: it is neither a file nor a directory"
    statuses=("${PIPESTATUS[@]}")
    set -e
    return "${statuses[0]}"
}

setup() {
    check_python
    make_venv
    local wanted
    wanted=$(setup_hash)
    if [[ -f "$STAMP" && $(cat "$STAMP") == "$wanted" ]]; then
        return 0
    fi
    say "installing the pinned requirements into .venv (first time: about a minute)"
    pip_install -r "$REPO/requirements.txt" || die "pip install -r requirements.txt failed"
    # Editable: source edits take effect without a reinstall, console scripts land in .venv/bin,
    # and config/ is read from the source tree (data_files are only installed by colcon/pip install .).
    # --no-build-isolation builds with the pinned setuptools already in .venv (no extra download).
    # --use-pep517: without it an older pip (Debian's 23.0) runs `setup.py develop`, which obeys
    # setup.cfg's ROS script_dir and hides the scripts in .venv/lib/usv_predictor instead of .venv/bin.
    say "installing usv_predictor (editable) into .venv"
    pip_install --no-deps --no-build-isolation --use-pep517 -e "$REPO" || die "pip install -e . failed"
    [[ -x "$VENV/bin/predictor" && -x "$VENV/bin/replay" ]] ||
        die "the editable install did not create .venv/bin/predictor and .venv/bin/replay"
    echo "$wanted" >"$STAMP"
}

# Both cores: two pytest-xdist workers, work stealing (the hidden-effect cases are long and uneven).
# Later options win, so `./run.sh test -n 0` runs in one process.
run_tests() {
    cd "$REPO"
    exec "$VENV/bin/python" -m pytest test/ -n "${USV_TEST_WORKERS:-2}" --dist worksteal "$@"
}

run_demo() {
    cd "$REPO"
    local out="$REPO/out/demo"
    rm -rf "$out"
    mkdir -p "$out"
    # ============================== DEMO: extend here ==============================
    # Each step is a `replay` command; results go to out/demo/.
    local replay="$VENV/bin/replay"
    say "1. simulate a 20/20 zig-zag in the Rizhao-like sea (current + wind + waves) and its calm twin"
    "$replay" simulate --manoeuvre zigzag --rudder 20 --duration 120 --sea rizhao --calm-twin \
        --output "$out/bags" --json "$out/simulate.json"
    say "2. seed 000's learned predictor on the shipped bags: dataset -> train -> export -> evaluate -> report"
    "$replay" dataset "$REPO"/bags/training "$REPO"/bags/sea_trial --val random_7_675rpm --output "$out/dataset.npz"
    # seed 000's network (NTF, tanh) trained on 10-step rollouts: with the one-step loss of the paper, seed 0 stops at
    # epoch 1 on the re-made bags (the validation run's loss is lowest there) and the fit check refuses that network
    # (it runs at 3.3 m/s where the boat runs at 5.3); docs/results/study_seed000.md
    "$replay" train "$out/dataset.npz" --features NTF --activation tanh --multi-step 10 --output "$out/model.pt" \
        --json "$out/train.json"
    "$replay" evaluate --model "$out/model.pt" --output "$out/evaluation"
    "$replay" report "$out/evaluation/evaluation.json" --output "$out/report"
    say "3. the predictor node fed from a shipped bag over DDS (use_sim_time + /clock): what it published"
    ROS_DOMAIN_ID=$((100 + $$ % 100)) ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST "$VENV/bin/python" \
        "$REPO/tools/play_bag.py" "$REPO/bags/sea_trial/turning_circle_stbd_20deg_700rpm" \
        --start 20 --seconds 8 --rate 1 --run-node | tee "$out/node_demo.txt"
    say "4. diagnosis of the shipped sea trial: the cause, the extended model and its gain on held-out manoeuvres"
    "$replay" diagnose "$REPO"/bags/sea_trial "$REPO"/bags/training --report "$out/diagnosis" \
        --export "$out/extended.pt" --json "$out/diagnosis.json"
    say "5. a twin-thruster boat (Otter class): zig-zags in differential thrust both ways with a hidden 8 % weaker" \
        "starboard thruster, diagnosed against a current (a few seconds)"
    for side in starboard port; do
        "$replay" simulate --vessel otter --manoeuvre zigzag --differential 0.4 --check 20 --throttle 0.6 \
            --duration 60 --side "$side" --heading 30 --effect thruster_imbalance --thruster-imbalance-pct 8 \
            --seed 11 --blind --output "$out/otter_bags"
    done
    "$replay" diagnose --vessel otter "$out/otter_bags" --hypotheses thruster_imbalance current --max-causes 1 \
        --no-gain --json "$out/otter_diagnosis.json"
    say "6. your boat (docs/your_boat.md, its commands as written): the Otter-class bags as an unknown boat," \
        "vessel init -> identify -> evaluate, diagnose -> the node with the boat's own model, fed over DDS"
    ROS_DOMAIN_ID=$((100 + ($$ + 1) % 100)) ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST "$VENV/bin/python" \
        "$REPO/tools/your_boat.py" "$out/your_boat" | tee "$out/your_boat.txt"
    # ============================ end of DEMO section ==============================
    say "demo done: evaluation report $out/report/report.md, diagnosis $out/diagnosis/report.md," \
        "twin-thruster diagnosis $out/otter_diagnosis.json, your boat $out/your_boat.txt, all in $out"
}

main() {
    local command=${1:-}
    [[ $# -gt 0 ]] && shift
    case "$command" in
        # not `setup && ...`: set -e is off inside a function called from an && list
        demo) setup; run_demo "$@" ;;
        test) setup; run_tests "$@" ;;
        setup) setup ;;
        -h | --help | help) usage ;;
        *) usage >&2 && exit 2 ;;
    esac
}

main "$@"
