#!/bin/bash
# The real-rig training loop (docs/real-rig.md) on the simulated rig, as a user with hardware runs it:
# record bags of the fringe stream (one scene each), label every sequence's composite frame with its own
# multi-shot depth, fine-tune the shipped network from its ONNX file, export it with rules chosen on the
# validation bags, and compare it with the shipped network on the test bags (against the multi-shot
# label: a recorded scene has no exact depth). About 10 minutes on 2 cores.
#
#   bash scripts/train_from_bags.sh [OUT]    (default out/from-bags; OUT must not exist)
set -eo pipefail  # not -u: the workspace's setup.bash reads unset variables
out=${1:-out/from-bags}
epochs=${EPOCHS:-20}
if [ -e "$out" ]; then
  echo "$out exists: give another folder" >&2
  exit 1
fi
source "$(dirname "${BASH_SOURCE[0]}")/env.bash"
shipped=$(python -c "from fpp_nodes.core.model import default_model_path; print(default_model_path())")
mkdir -p "$out/bags" "$out/logs"

record() {  # record SPLIT SCENE SEED: 12 s of the stream (about 16 sequences) into bags/SPLIT_SCENE_SEED
  local bag="$out/bags/$1_$2_$3" log="$out/logs/$1_$2_$3"
  ros2 run fpp_nodes pattern_projector >"$log.projector" 2>&1 &
  local projector=$!
  ros2 run fpp_nodes fringe_camera_sim --ros-args -p scene:="$2" -p seed:="$3" >"$log.camera" 2>&1 &
  local camera=$!
  ros2 run fpp_nodes record --ros-args -p output:="$bag" >"$log.record" 2>&1 &
  local recorder=$!
  sleep 12
  kill -INT "$recorder" && wait "$recorder"  # the recorder closes the bag on SIGINT
  kill -INT "$projector" "$camera" && wait "$projector" "$camera" || true
  python -m training.dataset --out "$out/data" --from-bag "$bag" --split "$1"
}

record train blocks 101
record train bust 102
record train freeform 103
record train floating 104
record val blocks 201
record val bust 202
record test sculpture 7
record test objects 301

python -m training.train --data "$out/data" --arch composite --width 16 --downsample 1 --crop 160 \
  --batch-size 8 --patience 4 --epochs "$epochs" --lr 5e-4 --init "$shipped" --out "$out/run"
python -m training.export "$out/run/best.pt" --out "$out/tuned.onnx"
python -m training.evaluate --data "$out/data" --families "$shipped" "$out/tuned.onnx" | tee "$out/table.txt"
