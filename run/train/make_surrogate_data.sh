#!/usr/bin/env bash
# The surrogate's data sets (docs/datasets.md, "The large data set"): 1 000 new held-out
# `small` beds (data-set seed 4), then the training set (seed 3, 20 000 beds by default).
# Survives a kill: run the same command again and it resumes where it stopped.
# Each finished data set's labels are appended to the label tables in labels/ as a new
# shard (docs/datasets.md, "Label tables"): commit them, they are what survives the machine.
# On a new machine the committed tables' records are rebuilt, not solved again
# (`amfe dataset --from-labels ... --solve-rest`), and only the rest is solved.
#
#   bash run/train/make_surrogate_data.sh [DIR] [TRAIN_COUNT]      (default DIR: ../data)
#
# After a kill the data-set lock is stale (amfe refuses to break it: docs/datasets.md,
# "One writer per file"). This script waits for the killed run's ranks to end and then
# removes a lock that amfe reports stale, once per start, saying so.
set -uo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
dir="${1:-$root/../data}"
train="${2:-20000}"
ranks="${AMFE_RANKS:-$(nproc)}"
bash "$root/run/setup.sh" >/dev/null || exit 1
source "$root/run/env.sh"
mkdir -p "$dir"

source_of() {  # source_of OUTPUT SEED: sets src, the arguments that say where records come from
    # The committed tables of the seed, when there are any and the run (if it has begun)
    # began from them: their records are rebuilt, the rest solved (--solve-rest).
    local out="$1" seed="$2" began="" f
    local tables=("$root"/labels/small_seed"${seed}"_labels_*.h5)
    for f in "$out" "$out.parts/params.json"; do
        if [ -e "$f" ]; then began="$f"; break; fi
    done
    if [ -e "${tables[0]}" ] && { [ -z "$began" ] || grep -aq from_labels "$began"; }; then
        src=(--from-labels "${tables[@]}" --solve-rest)   # the glob sorts by record range
    else
        src=(--seed "$seed" --scale small --solver auto)
    fi
}

make() {  # make OUTPUT COUNT SEED
    local out="$1" count="$2" seed="$3" log status
    for attempt in 1 2; do
        log="$(mktemp)"
        source_of "$out" "$seed"
        mpirun -n "$ranks" "$root/.venv/bin/amfe" dataset -o "$out" --count "$count" \
            "${src[@]}" 2> >(tee "$log" >&2)
        status=$?
        sleep 1    # let tee write the last lines
        if [ $status -eq 0 ]; then rm -f "$log"; return 0; fi
        if [ $attempt -eq 1 ] && grep -q "stale lock" "$log"; then
            sleep 10   # the ranks of a killed mpirun can outlive it by seconds
            echo "make_surrogate_data: removing the stale lock $out.lock (its run has ended)" >&2
            rm -f "$out.lock"
        else
            rm -f "$log"; return $status
        fi
        rm -f "$log"
    done
}

export_labels() {  # export_labels DATA: a shard in labels/ of the records its shards lack
    local msg
    mkdir -p "$root/labels"
    if msg="$("$root/.venv/bin/amfe" dataset --export-labels "$1" -o "$root/labels" 2>&1)"; then
        echo "$msg"
    elif grep -q "nothing to export" <<<"$msg"; then
        echo "make_surrogate_data: the labels of $1 are in $root/labels already" >&2
    else
        echo "$msg" >&2; return 1
    fi
}

t0=$(date +%s)
make "$dir/heldout_seed4_1000.h5" 1000 4 || exit $?
export_labels "$dir/heldout_seed4_1000.h5" || exit $?
make "$dir/train_seed3_${train}.h5" "$train" 3 || exit $?
export_labels "$dir/train_seed3_${train}.h5" || exit $?
echo "make_surrogate_data: done in $(( $(date +%s) - t0 )) s on $(nproc) cores ($(uname -n))"
