"""A Python rekon-replay: a frontend (messages/FRONTEND.md) that answers each frame with the pose a TUM trajectory
has for its timestamp. A keyframe starts whenever the camera moved 10 cm or 10 degrees from the last one; each new
keyframe goes out with a graph update of the poses announced (a frontend without a back end), the last one final.

    build/bin/rekon-mapper --out out &
    python python/examples/replay_frontend.py --trajectory DATA/groundtruth.txt &
    build/bin/rekon-player --dataset DATA --set player.wait_for=[replay,mapper]
"""
import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # python/, for running from a checkout
from rekon.bus import Bus  # noqa: E402
from rekon.frontend import Frontend, moved  # noqa: E402
from rekon.poses import Trajectory, between  # noqa: E402

p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
p.add_argument("--trajectory", required=True, help="TUM file: timestamp tx ty tz qx qy qz qw (camera to world)")
p.add_argument("--name", default="replay", help="the service name the player waits for (player.wait_for)")
p.add_argument("--lcm-url", help="the bus (default: rekon's lcm.url)")
p.add_argument("--timeout", type=float, default=600, help="give up after this many seconds")
args = p.parse_args()

trajectory = Trajectory(args.trajectory)
node = Frontend(args.name, Bus(args.lcm_url))
keyframe = None  # (id, world pose) of the newest keyframe


def on_frame(frame):
    global keyframe
    pose = trajectory.at(frame.timestamp)
    if pose is None:  # no pose within 20 ms: lost (FC9)
        node.tracked(frame.frame_id, frame.timestamp, -1, None)
    else:
        if keyframe is None or moved(keyframe[1], pose, 0.10, 10.0):
            keyframe = (len(node.keyframes), pose)
            node.keyframe(keyframe[0], frame.frame_id, frame.timestamp, pose)  # before the frame that names it
            node.graph_update()
        node.tracked(frame.frame_id, frame.timestamp, keyframe[0], between(keyframe[1], pose))
    node.ack(frame.frame_id)


def on_end(eos):
    node.graph_update(final=True)  # FC7: every keyframe, final
    node.done("optimiser")         # FC10: the mapper's final pass starts
    node.stop()


node.on_frame, node.on_end = on_frame, on_end
if not node.run(timeout_s=args.timeout):
    sys.exit(f"replay_frontend: no end of stream within {args.timeout:g} s")
print(f"replay_frontend: {node.last_frame_id + 1} frames, {len(node.keyframes)} keyframes", file=sys.stderr)
