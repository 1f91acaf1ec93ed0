#!/bin/sh
# The domain-randomised TransT fine-tuning (docs/transt.md "Domain randomisation"): progress,
# stop, export and evaluation, from the repository root.
#
#   sh benchmarks/transt_dr.sh progress   # last log line, last validation record, checkpoints
#   sh benchmarks/transt_dr.sh stop       # stop the run (checkpoints are written atomically)
#   sh benchmarks/transt_dr.sh export     # best checkpoint -> shipped weights, SHA-256, card
#   sh benchmarks/transt_dr.sh evaluate   # tests of the network and trust rule, benchmark
#
# PYTHON defaults to the project's virtual environment; OUT to runs/transt_train_dr; CKPT
# (export) to $OUT/best.pt (use $OUT/last.pt for the last one).
set -eu
PYTHON=${PYTHON:-.venv/bin/python}
OUT=${OUT:-runs/transt_train_dr}
CKPT=${CKPT:-$OUT/best.pt}
export PYTHONPATH=${PYTHONPATH:-.} OMP_WAIT_POLICY=PASSIVE
# The training command (also what the model card records); export reuses it with --export-from.
TRAIN="-m observer.transt.train --randomise --init-from observer/transt/weights/transt_small.pt \
 --yellow-fraction 0.5 --train-seed 11 --val-seed 12 --train-pairs 16000 --val-pairs 512 \
 --steps 2000 --lr 2e-4 --warmup 50 --threads 1 --render-workers 1 --out $OUT \
 --cache $(dirname "$OUT")/transt_cache"

case "${1:-}" in
start)  # resumes from $OUT/last.pt if present
    nohup "$PYTHON" $TRAIN > "$OUT.log" 2>&1 &
    echo $! > "$OUT.pid"
    echo "started pid $(cat "$OUT.pid"), log $OUT.log" ;;
progress)
    tail -c 400 "$OUT.log" | tr '\r' '\n' | tail -n 2; echo
    grep val_centre "$OUT/history.jsonl" | tail -n 1 || true
    ls -l "$OUT"/*.pt 2>/dev/null || echo "no checkpoint yet" ;;
stop)
    kill "$(cat "$OUT.pid")" && echo "stopped; resume with: sh $0 start" ;;
export)
    # evaluates the checkpoint (validation pairs, sequences, held-out families), writes the
    # weights, their .sha256 and MODEL_CARD.md; run it once (it continues the shipped weights)
    "$PYTHON" $TRAIN --export-from "$CKPT" --export observer/transt/weights/transt_small.pt
    # the ONNX Runtime backend is exported from the weights at load: check it builds and runs
    "$PYTHON" -c "from observer.transt.tracker import TransTTracker as T; t = T.small(); \
print('backend', t.backend)" ;;
evaluate)
    "$PYTHON" -m pytest tests/test_transt.py tests/test_gk_trust.py tests/test_trackers.py -q
    "$PYTHON" benchmarks/bench_tracking.py --cases all ;;
*)
    sed -n 2,13p "$0"; exit 2 ;;
esac
