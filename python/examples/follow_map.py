"""Follow the map of a live run in Python: keep the newest version of every block the mapper sends on MESH_BLOCKS
(asking for a full snapshot when started mid-run or after a lost message), and when the mapper is done, write the
whole mesh as a PLY: the run's mesh.ply, assembled from the bus.

    tools/rekon run --dataset DATA --out out/run &
    python python/examples/follow_map.py --out map.ply
"""
import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # python/, for running from a checkout
from rekon import msgs  # noqa: E402
from rekon.bus import Bus  # noqa: E402
from rekon.mesh import MeshError, MeshMap  # noqa: E402

p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
p.add_argument("--out", required=True, help="the PLY to write when the mapper is done")
p.add_argument("--lcm-url", help="the bus (default: rekon's lcm.url)")
p.add_argument("--timeout", type=float, default=600, help="give up after this many seconds")
args = p.parse_args()

bus, mesh_map = Bus(args.lcm_url), MeshMap()
state = {"done": False, "last": None, "gap": True, "rejected": 0, "asked": 0.0}


def on_blocks(channel, msg):
    last = state["last"]  # (sequence, part, parts) of the message before: a part lost on the way leaves blocks stale
    follows = last is not None and ((msg.sequence == last[0] and msg.part == last[1] + 1) or
                                    (msg.part == 0 and msg.sequence == last[0] + 1 and last[1] == last[2] - 1))
    state["gap"] = (state["gap"] or not follows) and not (msg.full and msg.part == 0)
    state["last"] = (msg.sequence, msg.part, msg.parts)
    try:
        mesh_map.apply(msg)
    except MeshError as err:
        state["rejected"] += 1
        print(f"follow_map: {err}", file=sys.stderr)


def ask_for_snapshot():
    if state["gap"] and time.monotonic() - state["asked"] > 2.0:
        request = msgs().mesh_request_t()
        request.requester = "follow_map"
        bus.publish("MESH_REQUEST", request)
        state["asked"] = time.monotonic()


bus.subscribe("MESH_BLOCKS", on_blocks)
bus.subscribe("DONE", lambda channel, msg: state.update(done=state["done"] or msg.service == "mapper"))
if not bus.run(timeout_s=args.timeout, until=lambda: state["done"], tick=ask_for_snapshot):
    sys.exit(f"follow_map: the mapper was not done within {args.timeout:g} s")
mesh = mesh_map.to_mesh()
mesh.write_ply(args.out)
print(f"follow_map: {mesh_map.messages} messages ({state['rejected']} rejected), {len(mesh_map.blocks)} blocks, "
      f"{len(mesh.vertices)} vertices, {len(mesh.faces)} triangles -> {args.out}", file=sys.stderr)
