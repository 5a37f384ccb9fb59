#!/usr/bin/env bash
# Main job: replay the held-out sample bag through the node graph (bag_player -> perception -> control,
# each its own process) with the default model; print the open-loop metrics and latency, write the report
# (report.md/json, steer/speed plots, segmentation overlays). CLOSED_LOOP=1 also drives one held-out
# route in the simulator through the node graph, prints success and trajectory RMSE and writes the
# video of the route (network and expert) next to its report. The replay's graph has the emergency brake between
# perception and control, as deployed; AEB=0 replays without it. The latency printed is camera frame -> the action
# the control takes: with the brake, the brake's hop is in it.
set -euo pipefail
cd "$(dirname "$0")/.."
bag=${1:-bags/sample}
checkpoint=${2:-$(.venv/bin/python -m msfsu_bringup.product checkpoint)}  # the product's (msfsu_bringup/product.yaml)
run_dir=${3:-runs/demo}
closed_loop=${CLOSED_LOOP:-0}
aeb=${AEB:-1}
case "$aeb" in
  0) eval_options=(--no-aeb) ;;
  1) eval_options=() ;;
  *) echo "demo: AEB must be 1 (the emergency brake in the graph, the default) or 0 (without it), not '$aeb'" >&2
     exit 2 ;;
esac

for needed in "$bag/metadata.yaml" "$checkpoint"; do
  if [ ! -e "$needed" ]; then
    echo "demo: $needed is missing. Give another bag/checkpoint: make demo SAMPLE_BAG=<bag dir> CHECKPOINT=<file.pt>" >&2
    exit 2
  fi
done
out="$run_dir/$(date +%Y%m%d-%H%M%S)"
.venv/bin/msfsu-eval-bag "$bag" --checkpoint "$checkpoint" --out "$out/open_loop" --cache-dir "$run_dir/cache" \
  "${eval_options[@]}"
echo "demo: open-loop report in $out/open_loop (report.md, actions.png, segmentation_overlays.png)"
if [ "$aeb" = 1 ]; then
  echo "demo: the latency above is camera frame -> the action the control takes, the emergency brake's hop included" \
    "(make demo AEB=0: without the brake)"
else
  echo "demo: replayed without the emergency brake (AEB=0): the latency above is camera frame -> perception's action"
fi
if [ "$closed_loop" = "1" ]; then
  # the first held-out one-turn route (CoRL2017 suite), the expert driving it too as the reference
  .venv/bin/msfsu-benchmark --checkpoint "$checkpoint" --suite corl2017 --conditions heldout --tasks one_turn \
    --routes-per-task 1 --video all --out "$out/closed_loop"
  echo "demo: closed-loop report in $out/closed_loop"
  find "$out/closed_loop/videos" -name '*.mp4' | sort | sed 's/^/demo: video of the route: /'
fi
# The graph's camera frames crossed over shared memory (the stack's Fast DDS profile); the same for your own ROS 2
# tools (ros2 bag record, rviz2) that handle camera frames:
echo "demo: camera frames cross over shared memory: export FASTRTPS_DEFAULT_PROFILES_FILE=$(.venv/bin/python -c \
'from msfsu_common.transport import FASTDDS_PROFILE; print(FASTDDS_PROFILE)') for your own ROS 2 tools (docs/realtime.md)"
