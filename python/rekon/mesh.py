"""The mapper's surface in Python: MESH_BLOCKS (messages/mesh.lcm) to numpy vertices, faces and colors, and to an
Open3D TriangleMesh when open3d is installed (it is not required). Mirrors common/.../mesh_blocks.hpp: MeshMap keeps
the newest version of every block, and to_mesh() joins them, merging the vertices two blocks share.

    mesh_map = MeshMap()
    bus.subscribe("MESH_BLOCKS", lambda channel, msg: mesh_map.apply(msg))
    ...
    mesh = mesh_map.to_mesh()          # Mesh(vertices (N,3) float32 m, faces (M,3) int32, colors (N,3) uint8 RGB)
    mesh.write_ply("map.ply"); o3d_mesh = mesh.to_open3d()
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# Limits of the C++ decoder (mesh_blocks.hpp), kept here so hostile input is refused alike.
MAX_RAW_BYTES = 64 << 20
MAX_BLOCK_COORD = 1 << 20


class MeshError(Exception):
    """A message or file that does not hold a mesh: one line."""


@dataclass
class Mesh:
    vertices: np.ndarray  # (N, 3) float32, metres
    faces: np.ndarray     # (M, 3) int32 vertex indices
    colors: np.ndarray    # (N, 3) uint8 RGB

    def to_open3d(self):
        """An open3d.geometry.TriangleMesh (vertex colors in [0, 1]); ImportError naming the fix without open3d."""
        try:
            import open3d as o3d
        except ImportError:
            raise ImportError("rekon.mesh.Mesh.to_open3d needs open3d (pip install open3d into the project's .venv); "
                              "the numpy arrays (vertices, faces, colors) need nothing") from None
        m = o3d.geometry.TriangleMesh()
        m.vertices = o3d.utility.Vector3dVector(self.vertices.astype(np.float64))
        m.triangles = o3d.utility.Vector3iVector(self.faces.astype(np.int32))
        m.vertex_colors = o3d.utility.Vector3dVector(self.colors.astype(np.float64) / 255.0)
        return m

    def write_ply(self, path) -> None:
        """Binary little-endian PLY, as rekon writes mesh.ply."""
        n, m = len(self.vertices), len(self.faces)
        header = (f"ply\nformat binary_little_endian 1.0\ncomment rekon python\nelement vertex {n}\n"
                  "property float x\nproperty float y\nproperty float z\n"
                  "property uchar red\nproperty uchar green\nproperty uchar blue\n"
                  f"element face {m}\nproperty list uchar int vertex_indices\nend_header\n")
        vert = np.empty(n, dtype=[("p", "<f4", 3), ("c", "u1", 3)])
        vert["p"], vert["c"] = self.vertices, self.colors
        face = np.empty(m, dtype=[("n", "u1"), ("i", "<i4", 3)])
        face["n"], face["i"] = 3, self.faces
        with open(path, "wb") as f:
            f.write(header.encode())
            f.write(vert.tobytes())
            f.write(face.tobytes())


@dataclass
class Block:
    x: int
    y: int
    z: int
    version: int
    cause: int              # 0 new data, 1 a correction, 2 the final pass
    vertices: np.ndarray    # (n, 3) float32 world metres; empty: the block was removed
    colors: np.ndarray      # (n, 3) uint8
    triangles: np.ndarray   # (m, 3) int32 indices into this block's vertices


def decode_blocks(msg) -> list[Block]:
    """Every block of one mesh_blocks_t, vertices in world metres. MeshError for inconsistent input."""
    if msg.block_voxels < 1 or msg.block_voxels > 256 or not (0 < msg.quantum <= msg.voxel_size):
        raise MeshError(f"mesh_blocks_t {msg.sequence}: block_voxels {msg.block_voxels}, quantum {msg.quantum}, "
                        f"voxel_size {msg.voxel_size} are not a mesh")
    if not 0 <= msg.raw_size <= MAX_RAW_BYTES:
        raise MeshError(f"mesh_blocks_t {msg.sequence}: raw_size {msg.raw_size} is out of range")
    need = sum(b.num_vertices * 9 + b.num_triangles * 6 for b in msg.blocks)
    if need != msg.raw_size:
        raise MeshError(f"mesh_blocks_t {msg.sequence}: the blocks need {need} bytes but raw_size is {msg.raw_size}")
    inflater = zlib.decompressobj()
    raw = inflater.decompress(bytes(msg.payload), msg.raw_size + 1)
    if len(raw) != msg.raw_size:
        raise MeshError(f"mesh_blocks_t {msg.sequence}: the payload does not inflate to raw_size {msg.raw_size}")
    block_size = msg.block_voxels * msg.voxel_size
    out, at = [], 0
    for h in msg.blocks:
        if max(abs(h.bx), abs(h.by), abs(h.bz)) > MAX_BLOCK_COORD:
            raise MeshError(f"mesh_blocks_t {msg.sequence}: block ({h.bx}, {h.by}, {h.bz}) is out of range")
        nv, nt = h.num_vertices, h.num_triangles
        quanta = np.frombuffer(raw, dtype="<u2", count=3 * nv, offset=at).reshape(nv, 3)
        at += 6 * nv
        colors = np.frombuffer(raw, dtype=np.uint8, count=3 * nv, offset=at).reshape(nv, 3).copy()
        at += 3 * nv
        triangles = np.frombuffer(raw, dtype="<u2", count=3 * nt, offset=at).reshape(nt, 3).astype(np.int32)
        at += 6 * nt
        if nt and triangles.max() >= nv:
            raise MeshError(f"mesh_blocks_t {msg.sequence}: block ({h.bx}, {h.by}, {h.bz}) has triangle index "
                            f"{int(triangles.max())} of {nv} vertices")
        corner = np.array([h.bx, h.by, h.bz], dtype=np.float64) * block_size
        vertices = (corner + quanta.astype(np.float64) * msg.quantum).astype(np.float32)
        out.append(Block(h.bx, h.by, h.bz, h.version, h.cause, vertices, colors, triangles))
    return out


class MeshMap:
    """The newest version of every block, as a subscriber to MESH_BLOCKS keeps it."""

    def __init__(self):
        self.blocks: dict[tuple[int, int, int], Block] = {}
        self.quantum = 0.0
        self.messages = 0
        self.full_parts = 0

    def apply(self, msg) -> int:
        """Decodes one mesh_blocks_t and keeps each block unless a newer version is held; an empty block removes it;
        the first part of a full snapshot first forgets every block. Returns how many blocks changed."""
        blocks = decode_blocks(msg)
        self.quantum = msg.quantum
        self.messages += 1
        if msg.full:
            self.full_parts += 1
            if msg.part == 0:
                self.blocks.clear()
        changed = 0
        for b in blocks:
            key = (b.x, b.y, b.z)
            held = self.blocks.get(key)
            if held is not None and held.version > b.version:
                continue
            changed += 1
            if len(b.vertices) == 0:
                self.blocks.pop(key, None)
            else:
                self.blocks[key] = b
        return changed

    def to_mesh(self) -> Mesh:
        """All blocks in one mesh; vertices that agree in quanta (shared by two blocks) are merged."""
        if not self.blocks:
            return Mesh(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32), np.zeros((0, 3), np.uint8))
        blocks = list(self.blocks.values())
        vertices = np.concatenate([b.vertices for b in blocks])
        colors = np.concatenate([b.colors for b in blocks])
        offsets = np.cumsum([0] + [len(b.vertices) for b in blocks[:-1]])
        faces = np.concatenate([b.triangles + o for b, o in zip(blocks, offsets)])
        scaled = vertices.astype(np.float64) * (1.0 / self.quantum)
        keys = (np.sign(scaled) * np.floor(np.abs(scaled) + 0.5)).astype(np.int64)  # std::llround, as the C++ map
        # First occurrence of each quanta triple keeps its position and color (as the C++ MeshMap does).
        _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
        order = np.argsort(first)  # merged vertices in the order they first appear
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        remap = rank[inverse.reshape(-1)]
        keep = first[order]
        return Mesh(vertices[keep], remap[faces].astype(np.int32), colors[keep])


def read_ply(path) -> Mesh:
    """A PLY (binary little-endian or ASCII; float/double x y z, optional uchar red green blue, faces as lists of
    three) as a Mesh; MeshError naming the file otherwise."""
    path = Path(path)
    data = path.read_bytes()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply") or end < 0:
        raise MeshError(f"{path}: not a PLY file")
    lines = data[:end].decode("ascii", "replace").splitlines()
    body = data[end + len(b"end_header\n"):]
    fmt, elements = None, []
    for line in lines:
        w = line.split()
        if not w:
            continue
        if w[0] == "format":
            fmt = w[1]
        elif w[0] == "element":
            elements.append((w[1], int(w[2]), []))
        elif w[0] == "property":
            elements[-1][2].append(w[1:])
    types = {"float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8", "uchar": "u1", "uint8": "u1",
             "char": "i1", "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4", "short": "<i2",
             "ushort": "<u2"}
    vertices = colors = faces = None
    if fmt == "ascii":
        tokens = body.split()
        at = 0
        for name, count, props in elements:
            if name == "vertex":
                k = len(props)
                table = np.array(tokens[at:at + k * count], dtype=np.float64).reshape(count, k)
                at += k * count
                names = [p[-1] for p in props]
                vertices = table[:, [names.index(c) for c in "xyz"]].astype(np.float32)
                if "red" in names:
                    colors = table[:, [names.index(c) for c in ("red", "green", "blue")]].astype(np.uint8)
            elif name == "face":
                rows = []
                for _ in range(count):
                    n = int(tokens[at])
                    rows.append([int(t) for t in tokens[at + 1:at + 1 + n]])
                    at += 1 + n
                faces = np.array(rows, dtype=np.int32).reshape(-1, 3)
    elif fmt == "binary_little_endian":
        at = 0
        for name, count, props in elements:
            if props and props[0][0] == "list":
                count_type, index_type = types[props[0][1]], types[props[0][2]]
                dt = np.dtype([("n", count_type), ("i", index_type, 3)])
                table = np.frombuffer(body, dtype=dt, count=count, offset=at)
                if count and not (table["n"] == 3).all():
                    raise MeshError(f"{path}: faces that are not triangles")
                faces = table["i"].astype(np.int32)
                at += dt.itemsize * count
                continue
            dt = np.dtype([(p[1], types[p[0]]) for p in props])
            table = np.frombuffer(body, dtype=dt, count=count, offset=at)
            at += dt.itemsize * count
            if name == "vertex":
                vertices = np.stack([table[c] for c in "xyz"], axis=1).astype(np.float32)
                if "red" in dt.names:
                    colors = np.stack([table[c] for c in ("red", "green", "blue")], axis=1).astype(np.uint8)
    else:
        raise MeshError(f"{path}: PLY format '{fmt}' is not read (binary_little_endian or ascii)")
    if vertices is None:
        raise MeshError(f"{path}: no vertex element")
    if faces is None:
        faces = np.zeros((0, 3), np.int32)
    if colors is None:
        colors = np.zeros((len(vertices), 3), np.uint8)
    return Mesh(vertices, faces, colors)
