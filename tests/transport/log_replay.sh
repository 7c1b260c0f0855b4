#!/usr/bin/env bash
# Records a whole `rekon run` with lcm-logger, then replays the log:
#   sensor/  fresh tracker, optimiser and mapper fed only the sensor channels
#            (REKON_FRAMES, REKON_END_OF_STREAM) by lcm-logplayer;
#   store/   a mapper fed the logged frames and tracked poses, stopped before
#            its final pass so that its keyframe store stays;
#   graph/   a mapper resuming from that store, fed only the pose and graph
#            channels (tracked frames, keyframes, graph updates, end, done);
#   mesh/    `rekon listen --mesh` fed only the map on the bus (MESH_BLOCKS)
#            and the done messages: the mesh a viewer of the log would show.
# Every process runs under a timeout; run it inside tests/support/in_netns.sh.
# usage: log_replay.sh BIN_DIR DATASET OUT_DIR
set -euo pipefail
bin=$1 data=$2 dir=$3
url="udpm://239.255.76.67:7667?ttl=0&recv_buf_size=8388608"
mkdir -p "$dir/sensor" "$dir/store" "$dir/graph"

# A service has subscribed to its inputs once it logs this line.
ready_line() {
  case $1 in
    tracker) echo "tracking levels" ;; optimiser) echo "pose graph:" ;; mapper) echo "mapper: KF strategy" ;;
    listener) echo "listening for the mesh" ;;
  esac
}
wait_ready() {  # FOLDER SERVICE...
  local folder=$1; shift
  for s in "$@"; do
    for _ in $(seq 1 600); do grep -q "$(ready_line "$s")" "$folder/$s.log" 2> /dev/null && break; sleep 0.1; done
    grep -q "$(ready_line "$s")" "$folder/$s.log" || { echo "rekon-$s did not start; see $folder/$s.log"; exit 1; }
  done
}
start() {  # FOLDER SERVICE [--set ...]
  local folder=$1 s=$2; shift 2
  timeout 240 "$bin/rekon-$s" --config "$dir/live/config.yaml" --out "$folder" "$@" > "$folder/$s.log" 2>&1 &
}

# The live run, recorded. Inline frames, so that the log holds the images.
timeout 300 lcm-logger --quiet --lcm-url="$url" "$dir/run.lcmlog" > /dev/null 2>&1 &
logger=$!
sleep 0.5
# The map goes on the bus unasked: the log is watched later (mesh/ below), not now.
timeout 240 "$bin/rekon" run --dataset "$data" --out "$dir/live" --set transport.mode=lcm \
  --set mapper.mesh_publish_unasked=true > "$dir/live.out" 2>&1
kill -INT $logger
wait $logger || true

# Sensor replay into fresh services: they finish through the usual done chain.
# The live run's config.yaml says mapper.remove_store_at_end=false (rekon run
# removes the store of the mapper it restarts); a mapper started by hand owns
# its store and removes it at its clean end.
owns_store="--set mapper.remove_store_at_end=true"
for s in tracker optimiser mapper; do start "$dir/sensor" $s --set mapper.store_segment=rekon_keyframes_sensor_$$ $owns_store; done
wait_ready "$dir/sensor" tracker optimiser mapper
# Half the recorded speed: the live run went as fast as its consumers
# acknowledged, and fresh services under a loaded machine (ctest -j2) once fell
# behind at full speed and lost 2 of 60 frames; the log has no back-pressure.
timeout 240 lcm-logplayer --speed 0.5 --lcm-url="$url" -e '^REKON_(FRAMES|END_OF_STREAM)$' "$dir/run.lcmlog"
wait

# A keyframe store from the logged frames and tracked poses; SIGTERM before
# the final pass keeps it.
store=rekon_keyframes_replay_$$
start "$dir/store" mapper --set mapper.store_segment=$store --set mapper.wait_for_optimiser=false --set transport.mode=lcm
mapper=$!
wait_ready "$dir/store" mapper
timeout 240 lcm-logplayer --speed 0.5 --lcm-url="$url" -e '^REKON_(FRAMES|TRACKED_FRAMES|KEYFRAMES)$' "$dir/run.lcmlog"
sleep 2  # the last frames through the mapper's queue
kill -TERM $mapper
wait $mapper || true

# Pose and graph channels only, into a mapper resuming from that store.
start "$dir/graph" mapper --set mapper.store_segment=$store --set mapper.resume=true $owns_store
wait_ready "$dir/graph" mapper
# No images: 5x the recorded speed is easy for the mapper.
timeout 240 lcm-logplayer --speed 5 --lcm-url="$url" -e '^REKON_(TRACKED_FRAMES|KEYFRAMES|GRAPH_UPDATES|END_OF_STREAM|DONE)$' "$dir/run.lcmlog"
wait

# The map on the bus, as the log holds it.
mkdir -p "$dir/mesh"
timeout 120 "$bin/rekon" listen --mesh "$dir/mesh/mesh.ply" --out "$dir/mesh" > "$dir/mesh/listener.log" 2>&1 &
wait_ready "$dir/mesh" listener
timeout 120 lcm-logplayer --speed 5 --lcm-url="$url" -e '^REKON_(MESH_BLOCKS|DONE)$' "$dir/run.lcmlog"
wait
