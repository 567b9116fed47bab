#!/usr/bin/env python3
"""Writes tests/assets/textured_chair.gltf: a sun-lit chair on a floor, textured the ways a Bevy user's glTF is.

* floor: a base-colour checker texture (sRGB PNG) repeated through KHR_texture_transform (scale 3);
* seat and back ("velvet"): white factor times an orange base-colour texture read through TEXCOORD_1;
* legs ("wood"): metallicFactor 1.0 with a metallic-roughness texture that makes only one eighth of each leg
  metal (blue channel), and a yellow-brown base-colour texture.
A KHR_lights_punctual directional light (the sun) and a camera. The tracer must read every one of these as
Bevy's StandardMaterial does. Standard library only: `python3 tests/assets/make_textured_chair.py`.
"""
import base64
import json
import struct
import zlib

from gltf_helpers import look_at_quat
from pathlib import Path


def png(width, height, rgba_rows):
    def chunk(kind, data):
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)
    raw = b"".join(b"\x00" + bytes(v for px in row for v in px) for row in rgba_rows)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def data_uri(data):
    return "data:image/png;base64," + base64.b64encode(data).decode()


checker = png(4, 4, [[(240, 140, 40, 255) if (x + y) % 2 else (230, 230, 225, 255) for x in range(4)] for y in range(4)])
orange = png(2, 2, [[(235, 110, 30, 255)] * 2] * 2)
wood = png(2, 2, [[(190, 150, 70, 255)] * 2] * 2)
# Metallic in blue, roughness in green: one texel column of eight is metal.
metal = png(8, 1, [[(0, 255, 255 if x == 0 else 0, 255) for x in range(8)]])

positions, normals, uv0, uv1 = [], [], [], []
groups = {}  # material -> indices


def quad(corners, normal, material, uv_scale=1.0):
    base = len(positions)
    positions.extend(corners)
    normals.extend([normal] * 4)
    square = [(0, 0), (1, 0), (1, 1), (0, 1)]
    uv0.extend([(u * uv_scale, v * uv_scale) for u, v in square])
    uv1.extend([(1 - u, v) for u, v in square])
    groups.setdefault(material, []).extend([base, base + 1, base + 2, base, base + 2, base + 3])


def box(cx, cy, cz, hx, hy, hz, material):
    x0, x1, y0, y1, z0, z1 = cx - hx, cx + hx, cy - hy, cy + hy, cz - hz, cz + hz
    quad([(x0, y1, z0), (x0, y1, z1), (x1, y1, z1), (x1, y1, z0)], (0, 1, 0), material)
    quad([(x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)], (0, -1, 0), material)
    quad([(x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)], (0, 0, 1), material)
    quad([(x0, y0, z0), (x0, y1, z0), (x1, y1, z0), (x1, y0, z0)], (0, 0, -1), material)
    quad([(x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1)], (1, 0, 0), material)
    quad([(x0, y0, z0), (x0, y0, z1), (x0, y1, z1), (x0, y1, z0)], (-1, 0, 0), material)


quad([(-2, 0, -2), (-2, 0, 2), (2, 0, 2), (2, 0, -2)], (0, 1, 0), 0)
box(0, 0.5, 0, 0.4, 0.05, 0.4, 1)           # seat
box(0, 0.95, -0.37, 0.4, 0.4, 0.03, 1)      # back
for sx in (-1, 1):
    for sz in (-1, 1):
        box(0.34 * sx, 0.225, 0.34 * sz, 0.04, 0.225, 0.04, 2)  # legs

buffer = b""
buffer_views, accessors = [], []


def add(data, target, count, kind, component=5126, bounds=None):
    global buffer
    buffer_views.append({"buffer": 0, "byteOffset": len(buffer), "byteLength": len(data), "target": target})
    buffer += data
    accessor = {"bufferView": len(buffer_views) - 1, "componentType": component, "count": count, "type": kind}
    if bounds:
        accessor["min"], accessor["max"] = bounds
    accessors.append(accessor)
    return len(accessors) - 1


lo = [min(p[i] for p in positions) for i in range(3)]
hi = [max(p[i] for p in positions) for i in range(3)]
a_pos = add(b"".join(struct.pack("<3f", *p) for p in positions), 34962, len(positions), "VEC3", bounds=(lo, hi))
a_nrm = add(b"".join(struct.pack("<3f", *n) for n in normals), 34962, len(normals), "VEC3")
a_uv0 = add(b"".join(struct.pack("<2f", *t) for t in uv0), 34962, len(uv0), "VEC2")
a_uv1 = add(b"".join(struct.pack("<2f", *t) for t in uv1), 34962, len(uv1), "VEC2")
primitives = []
for material, idx in sorted(groups.items()):
    a_idx = add(b"".join(struct.pack("<I", i) for i in idx), 34963, len(idx), "SCALAR", component=5125)
    primitives.append({"attributes": {"POSITION": a_pos, "NORMAL": a_nrm, "TEXCOORD_0": a_uv0, "TEXCOORD_1": a_uv1},
                       "indices": a_idx, "material": material})


gltf = {
    "asset": {"version": "2.0", "generator": "bevy_diffuse_gi tests/assets/make_textured_chair.py"},
    "extensionsUsed": ["KHR_lights_punctual", "KHR_texture_transform"],
    "extensions": {"KHR_lights_punctual": {"lights": [
        {"name": "sun", "type": "directional", "color": [1.0, 0.97, 0.92], "intensity": 4.0},
    ]}},
    "scene": 0,
    "scenes": [{"nodes": [0, 1, 2]}],
    "nodes": [
        {"name": "chair and floor", "mesh": 0},
        {"name": "sun", "rotation": look_at_quat([0, 0, 0], [-0.35, -1.0, -0.55]),
         "extensions": {"KHR_lights_punctual": {"light": 0}}},
        {"name": "camera", "camera": 0, "translation": [1.3, 1.5, 1.9],
         "rotation": look_at_quat([1.3, 1.5, 1.9], [0.0, 0.45, 0.0])},
    ],
    "cameras": [{"type": "perspective", "perspective": {"yfov": 0.9, "znear": 0.05}}],
    "meshes": [{"name": "chair", "primitives": primitives}],
    "images": [{"uri": data_uri(d)} for d in (checker, orange, wood, metal)],
    "samplers": [{"magFilter": 9729, "minFilter": 9729, "wrapS": 10497, "wrapT": 10497}],
    "textures": [{"sampler": 0, "source": i} for i in range(4)],
    "materials": [
        {"name": "floor", "pbrMetallicRoughness": {
            "baseColorTexture": {"index": 0, "extensions": {"KHR_texture_transform": {"scale": [3.0, 3.0]}}},
            "metallicFactor": 0.0, "roughnessFactor": 1.0}},
        {"name": "velvet", "pbrMetallicRoughness": {
            "baseColorTexture": {"index": 1, "texCoord": 1}, "metallicFactor": 0.0, "roughnessFactor": 1.0}},
        {"name": "wood", "pbrMetallicRoughness": {
            "baseColorTexture": {"index": 2}, "metallicRoughnessTexture": {"index": 3},
            "metallicFactor": 1.0, "roughnessFactor": 1.0}},
    ],
    "accessors": accessors,
    "bufferViews": buffer_views,
    "buffers": [{"byteLength": len(buffer), "uri": "data:application/octet-stream;base64," + base64.b64encode(buffer).decode()}],
}
out = Path(__file__).with_name("textured_chair.gltf")
out.write_text(json.dumps(gltf, indent=1))
print(f"wrote {out} ({len(positions)} vertices)")
