#!/usr/bin/env python3
"""Writes variants of textured_chair.gltf whose textures are external JPEG or WebP files, and one whose
first texture points at a file that does not exist, for tests/gpu_gltf.rs:

  textured_chair_jpeg.gltf  + textured_chair_*.jpg
  textured_chair_webp.gltf  + textured_chair_*.webp
  textured_chair_ktx2.gltf  + textured_chair_*.ktx2 (uncompressed RGBA8, written without a KTX tool)
  missing_texture.gltf      (images[0] is does_not_exist.png)

Needs Pillow (only to regenerate the committed files): python3 make_image_format_variants.py
"""
import base64
import io
import json
import pathlib

from PIL import Image

here = pathlib.Path(__file__).parent
chair = json.loads((here / "textured_chair.gltf").read_text())


def decoded(uri):
    header, data = uri.split(",", 1)
    assert header == "data:image/png;base64", header
    return Image.open(io.BytesIO(base64.b64decode(data))).convert("RGB")


for fmt, ext, mime in [("JPEG", "jpg", "image/jpeg"), ("WEBP", "webp", "image/webp")]:
    variant = json.loads(json.dumps(chair))
    for i, image in enumerate(variant["images"]):
        name = f"textured_chair_{i}.{ext}"
        picture = decoded(image["uri"])
        # Lossless where the format allows, so the colours stay those of the PNGs.
        options = {"quality": 100, "subsampling": 0} if fmt == "JPEG" else {"lossless": True}
        picture.save(here / name, fmt, **options)
        variant["images"][i] = {"uri": name, "mimeType": mime}
    (here / f"textured_chair_{ext if ext != 'jpg' else 'jpeg'}.gltf").write_text(json.dumps(variant, indent=1))

missing = json.loads(json.dumps(chair))
missing["images"][0] = {"uri": "does_not_exist.png"}
(here / "missing_texture.gltf").write_text(json.dumps(missing, indent=1))


# KTX2 (Khronos Texture 2.0), the GPU-ready container Bevy users ship: uncompressed 8-bit RGBA, one mip
# level, no supercompression, written here field by field (KTX 2.0 spec §3, basic data format descriptor
# §4 of the Khronos Data Format spec) so no KTX tool is needed. Base colour textures are sRGB
# (VK_FORMAT_R8G8B8A8_SRGB), the metallic-roughness texture linear (VK_FORMAT_R8G8B8A8_UNORM).
import struct

KTX2_IDENTIFIER = bytes([0xAB, 0x4B, 0x54, 0x58, 0x20, 0x32, 0x30, 0xBB, 0x0D, 0x0A, 0x1A, 0x0A])
VK_FORMAT_R8G8B8A8_UNORM = 37
VK_FORMAT_R8G8B8A8_SRGB = 43


def ktx2_rgba8(picture, srgb):
    rgba = picture.convert("RGBA")
    # Bevy's KTX2 loader makes a one-texel-high image a 1D texture, which a material cannot bind: repeat
    # the row (every v then reads the same texels).
    if rgba.size[1] == 1:
        rgba = rgba.resize((rgba.size[0], 2), Image.NEAREST)
    width, height = rgba.size
    pixels = rgba.tobytes()
    # Basic data format descriptor: RGBSDA colour model, BT.709 primaries, sRGB or linear transfer,
    # 4 bytes per texel in plane 0, one 8-bit sample per channel (alpha always linear).
    samples = b""
    for i, channel in enumerate([0, 1, 2, 15]):
        qualifiers = 0x10 if (channel == 15 and srgb) else 0
        samples += struct.pack("<HBBIII", 8 * i, 7, channel | qualifiers, 0, 0, 255)
    block = struct.pack(
        "<IHHBBBBBBBBBBBBBBBB",
        0,  # vendor 0 (Khronos), descriptor type 0 (basic)
        2,  # version 2
        24 + len(samples),
        1,  # KHR_DF_MODEL_RGBSDA
        1,  # KHR_DF_PRIMARIES_BT709
        2 if srgb else 1,  # KHR_DF_TRANSFER_SRGB / LINEAR
        0,  # straight alpha
        0, 0, 0, 0,  # texel block 1×1×1×1
        4, 0, 0, 0, 0, 0, 0, 0,  # bytes in plane 0..7
    ) + samples
    dfd = struct.pack("<I", 4 + len(block)) + block
    header_size = 12 + 9 * 4 + 4 * 4 + 2 * 8 + 3 * 8  # identifier, header, index, one level entry
    dfd_offset = header_size
    data_offset = dfd_offset + len(dfd)
    data_offset += (-data_offset) % 16
    out = KTX2_IDENTIFIER
    out += struct.pack(
        "<9I",
        VK_FORMAT_R8G8B8A8_SRGB if srgb else VK_FORMAT_R8G8B8A8_UNORM,
        1,  # type size
        width,
        height,
        0,  # depth
        0,  # layers
        1,  # faces
        1,  # levels
        0,  # no supercompression
    )
    out += struct.pack("<IIIIQQ", dfd_offset, len(dfd), 0, 0, 0, 0)
    out += struct.pack("<QQQ", data_offset, len(pixels), len(pixels))
    assert len(out) == header_size
    out += dfd
    out += b"\0" * (data_offset - len(out))
    return out + pixels


linear_images = {tex["source"] for m in chair["materials"] for key, tex in m.get("pbrMetallicRoughness", {}).items()
                 if key == "metallicRoughnessTexture" for tex in [chair["textures"][tex["index"]]]}
variant = json.loads(json.dumps(chair))
for i, image in enumerate(variant["images"]):
    name = f"textured_chair_{i}.ktx2"
    (here / name).write_bytes(ktx2_rgba8(decoded(image["uri"]), srgb=i not in linear_images))
    variant["images"][i] = {"uri": name}
(here / "textured_chair_ktx2.gltf").write_text(json.dumps(variant, indent=1))
