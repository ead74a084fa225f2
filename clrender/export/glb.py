"""glTF 2.0 binary (``.glb``) files of coloured triangle meshes and perspective cameras.

One JSON chunk and one binary chunk: per mesh node POSITION, NORMAL (unit), COLOR_0 (RGBA,
normalised unsigned shorts, linear as glTF defines vertex colours) and UNSIGNED_INT
indices, with an unlit material (``KHR_materials_unlit``: the colours are the captured
radiance, lighting included); per camera a node looking down its -z with +y up. Positions
are given in the datasets' Z-up scene space and written +Y up (glTF's axes).

Examples:
    >>> write_glb("scene.glb", [MeshNode("outer", v, f, rgb)], [("test_000", camera)])
    >>> read_glb("scene.glb")["outer"]["COLOR_0"]         # (V, 3) float32 sRGB in [0, 1]

References: the glTF 2.0 specification (Khronos), sections 3.7 (binary buffers, alignment),
3.9.2 (COLOR_0), 4.4 (GLB container).
"""
from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import atomic_write

# Z-up scene space -> glTF's +Y up: (x, y, z) -> (x, z, -y), a rotation about x.
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
_MAGIC, _VERSION, _JSON, _BIN = 0x46546C67, 2, 0x4E4F534A, 0x004E4942
_FLOAT, _USHORT, _UINT = 5126, 5123, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963


@dataclass
class MeshNode:
    """A mesh to write.

    Attributes:
        name: the node's name.
        vertices: (V, 3) float positions, Z-up scene units.
        faces: (F, 3) int vertex indices, counter-clockwise seen from outside.
        colours: (V, 3) float sRGB in [0, 1].
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    colours: np.ndarray


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) float32 unit normals: area-weighted face normals summed at each vertex; +z
    (scene up) where they cancel or no face uses the vertex."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    face_n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])   # 2 x area
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], face_n)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.where(length > 1e-12, n / np.maximum(length, 1e-300), [0.0, 0.0, 1.0])
    return n.astype(np.float32)


class _Buffer:
    """The binary chunk: views of 4-byte aligned arrays, and their accessors."""

    def __init__(self):
        self.parts, self.size, self.views, self.accessors = [], 0, [], []

    def add(self, array: np.ndarray, component: int, kind: str, target: int,
            normalized: bool = False, bounds: bool = False) -> int:
        data = np.ascontiguousarray(array).tobytes()
        self.views.append({"buffer": 0, "byteOffset": self.size, "byteLength": len(data),
                           "target": target})
        pad = -len(data) % 4
        self.parts.append(data + b"\0" * pad)
        self.size += len(data) + pad
        accessor = {"bufferView": len(self.views) - 1, "componentType": component,
                    "count": int(len(array)), "type": kind}
        if normalized:
            accessor["normalized"] = True
        if bounds:
            accessor["min"] = [float(x) for x in array.min(axis=0)]
            accessor["max"] = [float(x) for x in array.max(axis=0)]
        self.accessors.append(accessor)
        return len(self.accessors) - 1


def _mesh_primitive(buf: _Buffer, node: MeshNode) -> dict:
    v = np.asarray(node.vertices, np.float64)
    f = np.asarray(node.faces, np.uint32)
    if len(f) == 0 or len(v) == 0:
        raise ValueError(f"mesh {node.name!r} has no triangles")
    rgba = np.ones((len(v), 4))
    rgba[:, :3] = srgb_to_linear(np.asarray(node.colours, np.float64))
    position = (v @ Z_UP_TO_Y_UP.T).astype(np.float32)
    normal = vertex_normals(v, f) @ Z_UP_TO_Y_UP.T.astype(np.float32)
    return {"attributes": {
                "POSITION": buf.add(position, _FLOAT, "VEC3", _ARRAY_BUFFER, bounds=True),
                "NORMAL": buf.add(normal.astype(np.float32), _FLOAT, "VEC3", _ARRAY_BUFFER),
                "COLOR_0": buf.add(np.round(rgba * 65535).astype(np.uint16), _USHORT, "VEC4",
                                   _ARRAY_BUFFER, normalized=True)},
            "indices": buf.add(f.reshape(-1), _UINT, "SCALAR", _ELEMENT_ARRAY_BUFFER),
            "material": 0, "mode": 4}


def _camera(camera) -> tuple[dict, list[float]]:
    """(glTF perspective camera, column-major node matrix) of a clrender Camera."""
    yfov = 2.0 * np.arctan(camera.height / (2.0 * camera.fy))
    pose = np.eye(4)
    pose[:3, :4] = Z_UP_TO_Y_UP @ camera.c2w[:3, :4]
    return ({"type": "perspective",
             "perspective": {"aspectRatio": camera.width / camera.height, "yfov": float(yfov),
                             "znear": 0.01}},
            [float(x) for x in pose.T.reshape(-1)])


def glb_bytes(meshes: list[MeshNode], cameras=(), generator: str = "clrender") -> bytes:
    """The ``.glb`` file of ``meshes`` and ``cameras`` ([(name, Camera)]) as bytes."""
    buf = _Buffer()
    nodes, gltf_meshes, gltf_cameras = [], [], []
    for node in meshes:
        gltf_meshes.append({"name": node.name, "primitives": [_mesh_primitive(buf, node)]})
        nodes.append({"name": node.name, "mesh": len(gltf_meshes) - 1})
    for name, camera in cameras:
        cam, matrix = _camera(camera)
        gltf_cameras.append({"name": name, **cam})
        nodes.append({"name": name, "camera": len(gltf_cameras) - 1, "matrix": matrix})
    doc = {"asset": {"version": "2.0", "generator": generator},
           "extensionsUsed": ["KHR_materials_unlit"],
           "scene": 0, "scenes": [{"nodes": list(range(len(nodes)))}], "nodes": nodes,
           "meshes": gltf_meshes,
           "materials": [{"name": "vertex colours", "extensions": {"KHR_materials_unlit": {}},
                          "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1],
                                                   "metallicFactor": 0.0,
                                                   "roughnessFactor": 1.0}}],
           "buffers": [{"byteLength": buf.size}], "bufferViews": buf.views,
           "accessors": buf.accessors}
    if gltf_cameras:
        doc["cameras"] = gltf_cameras
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    binary = b"".join(buf.parts)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return b"".join([struct.pack("<III", _MAGIC, _VERSION, total),
                     struct.pack("<II", len(text), _JSON), text,
                     struct.pack("<II", len(binary), _BIN), binary])


def write_glb(path, meshes: list[MeshNode], cameras=()) -> Path:
    """Write :func:`glb_bytes` to ``path`` (a temporary file renamed into place)."""
    data = glb_bytes(meshes, cameras)
    return atomic_write(Path(path), lambda tmp: Path(tmp).write_bytes(data))


def read_glb(path) -> dict:
    """{mesh node name: {"POSITION" (V, 3) Z-up, "NORMAL" (V, 3) Z-up, "COLOR_0" (V, 3)
    sRGB, "indices" (F, 3)}} of a file :func:`write_glb` wrote, plus "cameras": the
    camera nodes' names."""
    data = Path(path).read_bytes()
    magic, _, total = struct.unpack_from("<III", data)
    if magic != _MAGIC or total != len(data):
        raise ValueError(f"{path}: not a glTF binary file")
    n_json, _ = struct.unpack_from("<II", data, 12)
    doc = json.loads(data[20:20 + n_json])
    binary = data[28 + n_json:]
    dtypes = {_FLOAT: np.float32, _USHORT: np.uint16, _UINT: np.uint32}
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}

    def accessor(i):
        a = doc["accessors"][i]
        view = doc["bufferViews"][a["bufferView"]]
        raw = np.frombuffer(binary, dtypes[a["componentType"]], a["count"] * width[a["type"]],
                            view["byteOffset"])
        return raw.reshape(a["count"], -1) if width[a["type"]] > 1 else raw

    back = Z_UP_TO_Y_UP                                    # y-up -> z-up: the inverse (R^T)
    out = {"cameras": [n["name"] for n in doc["nodes"] if "camera" in n]}
    for node in doc["nodes"]:
        if "mesh" not in node:
            continue
        prim = doc["meshes"][node["mesh"]]["primitives"][0]
        attr = prim["attributes"]
        colour = accessor(attr["COLOR_0"])[:, :3] / 65535.0
        out[node["name"]] = {"POSITION": accessor(attr["POSITION"]) @ back,
                             "NORMAL": accessor(attr["NORMAL"]) @ back,
                             "COLOR_0": linear_to_srgb(colour).astype(np.float32),
                             "indices": accessor(prim["indices"]).reshape(-1, 3)}
    return out
