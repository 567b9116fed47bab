#!/usr/bin/env python3
"""Writes variants of textured_chair.gltf whose textures are external JPEG or WebP files, and one whose
first texture points at a file that does not exist, for tests/gpu_gltf.rs:

  textured_chair_jpeg.gltf  + textured_chair_*.jpg
  textured_chair_webp.gltf  + textured_chair_*.webp
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
