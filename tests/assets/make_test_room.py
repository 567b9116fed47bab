#!/usr/bin/env python3
"""Writes tests/assets/test_room.gltf: a small room for glTF tests of bevy_diffuse_gi.

A 4 x 2.5 x 4 m room (floor, ceiling, four walls facing inward; the +z wall has a 1.2 m wide doorway),
a red box on the floor, a KHR_lights_punctual spot light under the ceiling pointing down, a dim point
light, and a perspective camera looking into the room. Units: metres, Y up. Only the standard library is
used, so the file can be regenerated anywhere: `python3 tests/assets/make_test_room.py`.
"""
import base64
import json
import math
import struct

from gltf_helpers import look_at_quat
from pathlib import Path

positions, normals, indices = [], [], []
primitives = []  # (first index, index count, material)


def quad(corners, normal, material):
    base = len(positions)
    first = len(indices)
    positions.extend(corners)
    normals.extend([normal] * 4)
    indices.extend([base, base + 1, base + 2, base, base + 2, base + 3])
    primitives.append((first, 6, material))


def inward_box(x0, x1, y0, y1, z0, z1, materials, door=None):
    # floor (+y), ceiling (-y)
    quad([(x0, y0, z0), (x0, y0, z1), (x1, y0, z1), (x1, y0, z0)], (0, 1, 0), materials["floor"])
    quad([(x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1)], (0, -1, 0), materials["wall"])
    # walls facing inward
    quad([(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0)], (0, 0, 1), materials["wall"])
    quad([(x0, y0, z0), (x0, y1, z0), (x0, y1, z1), (x0, y0, z1)], (1, 0, 0), materials["accent"])
    quad([(x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1)], (-1, 0, 0), materials["wall"])
    # +z wall with a doorway between door[0] and door[1] up to door[2]
    d0, d1, dh = door
    quad([(x0, y0, z1), (d0, y0, z1), (d0, y1, z1), (x0, y1, z1)], (0, 0, -1), materials["wall"])
    quad([(d1, y0, z1), (x1, y0, z1), (x1, y1, z1), (d1, y1, z1)], (0, 0, -1), materials["wall"])
    quad([(d0, dh, z1), (d1, dh, z1), (d1, y1, z1), (d0, y1, z1)], (0, 0, -1), materials["wall"])


def outward_box(cx, cy, cz, hx, hy, hz, material):
    x0, x1, y0, y1, z0, z1 = cx - hx, cx + hx, cy - hy, cy + hy, cz - hz, cz + hz
    quad([(x0, y1, z0), (x0, y1, z1), (x1, y1, z1), (x1, y1, z0)], (0, 1, 0), material)
    quad([(x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)], (0, -1, 0), material)
    quad([(x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)], (0, 0, 1), material)
    quad([(x0, y0, z0), (x0, y1, z0), (x1, y1, z0), (x1, y0, z0)], (0, 0, -1), material)
    quad([(x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1)], (1, 0, 0), material)
    quad([(x0, y0, z0), (x0, y0, z1), (x0, y1, z1), (x0, y1, z0)], (-1, 0, 0), material)


MATERIALS = [
    ("white", [0.8, 0.8, 0.8, 1.0]),
    ("floor", [0.6, 0.55, 0.5, 1.0]),
    ("blue", [0.1, 0.2, 0.7, 1.0]),
    ("red", [0.75, 0.08, 0.06, 1.0]),
]
inward_box(-2, 2, 0, 2.5, -2, 2, {"floor": 1, "wall": 0, "accent": 2}, door=(-0.6, 0.6, 2.0))
outward_box(0.6, 0.4, -0.6, 0.4, 0.4, 0.4, 3)

# Interleave nothing: two attribute arrays and one index array in one buffer.
pos_bytes = b"".join(struct.pack("<3f", *p) for p in positions)
nrm_bytes = b"".join(struct.pack("<3f", *n) for n in normals)
idx_bytes = b"".join(struct.pack("<I", i) for i in indices)
buffer = pos_bytes + nrm_bytes + idx_bytes
lo = [min(p[i] for p in positions) for i in range(3)]
hi = [max(p[i] for p in positions) for i in range(3)]

accessors = [
    {"bufferView": 0, "componentType": 5126, "count": len(positions), "type": "VEC3", "min": lo, "max": hi},
    {"bufferView": 1, "componentType": 5126, "count": len(normals), "type": "VEC3"},
]
buffer_views = [
    {"buffer": 0, "byteOffset": 0, "byteLength": len(pos_bytes), "target": 34962},
    {"buffer": 0, "byteOffset": len(pos_bytes), "byteLength": len(nrm_bytes), "target": 34962},
    {"buffer": 0, "byteOffset": len(pos_bytes) + len(nrm_bytes), "byteLength": len(idx_bytes), "target": 34963},
]
# One glTF primitive per material: merge the quads of each material.
mesh_primitives = []
for material in range(len(MATERIALS)):
    idx = [i for (first, count, m) in primitives if m == material for i in indices[first:first + count]]
    if not idx:
        continue
    data = b"".join(struct.pack("<I", i) for i in idx)
    buffer_views.append({"buffer": 0, "byteOffset": len(buffer), "byteLength": len(data), "target": 34963})
    buffer += data
    accessors.append({"bufferView": len(buffer_views) - 1, "componentType": 5125, "count": len(idx), "type": "SCALAR"})
    mesh_primitives.append({
        "attributes": {"POSITION": 0, "NORMAL": 1},
        "indices": len(accessors) - 1,
        "material": material,
    })
# The combined index view (2) is unused by primitives; drop its bytes from nothing (kept for simplicity).

down = [-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)]  # rotates -Z onto -Y
gltf = {
    "asset": {"version": "2.0", "generator": "bevy_diffuse_gi tests/assets/make_test_room.py"},
    "extensionsUsed": ["KHR_lights_punctual"],
    "extensions": {"KHR_lights_punctual": {"lights": [
        {"name": "spot", "type": "spot", "color": [1.0, 0.95, 0.9], "intensity": 60.0,
         "spot": {"innerConeAngle": 0.5, "outerConeAngle": 0.7}},
        {"name": "point", "type": "point", "color": [0.9, 0.9, 1.0], "intensity": 5.0},
    ]}},
    "scene": 0,
    "scenes": [{"nodes": [0, 1, 2, 3]}],
    "nodes": [
        {"name": "room", "mesh": 0},
        {"name": "spot light", "translation": [0.0, 2.4, -0.5], "rotation": down,
         "extensions": {"KHR_lights_punctual": {"light": 0}}},
        {"name": "point light", "translation": [-1.3, 1.8, 1.2],
         "extensions": {"KHR_lights_punctual": {"light": 1}}},
        {"name": "camera", "camera": 0, "translation": [1.6, 1.6, 1.7],
         "rotation": look_at_quat([1.6, 1.6, 1.7], [-0.5, 0.5, -1.2])},
    ],
    "cameras": [{"type": "perspective", "perspective": {"yfov": 1.1, "znear": 0.05}}],
    "meshes": [{"name": "room", "primitives": mesh_primitives}],
    "materials": [
        {"name": name, "pbrMetallicRoughness": {"baseColorFactor": color, "metallicFactor": 0.0,
                                                 "roughnessFactor": 1.0}}
        for name, color in MATERIALS
    ],
    "accessors": accessors,
    "bufferViews": buffer_views,
    "buffers": [{"byteLength": len(buffer),
                 "uri": "data:application/octet-stream;base64," + base64.b64encode(buffer).decode()}],
}
out = Path(__file__).with_name("test_room.gltf")
out.write_text(json.dumps(gltf, indent=1))
print(f"wrote {out} ({len(positions)} vertices, {len(indices) // 3} triangles)")
