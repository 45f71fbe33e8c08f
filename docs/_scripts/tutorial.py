"""Tutorial: a bundled HDRI into a camera frame, the model's two lighting maps, SH irradiance, augmentation.

Run alone with `python docs/_scripts/tutorial.py` (figures go to out/tutorial/). The docs build runs it
section by section (the `# [name]` lines) and shows each section's code beside what it printed, so the
code on the tutorial page is exactly the code that ran.
"""

from pathlib import Path

import numpy as np
import torch
from PIL import Image

import gaffer_envmap as ge
from gaffer_envmap.io import read_envmap
from gaffer_envmap.preview import tonemap_preview
from gaffer_envmap.sh import irradiance_brute_force

OUT = Path(globals().get("OUT", "out/tutorial"))
OUT.mkdir(parents=True, exist_ok=True)
np.set_printoptions(precision=3, suppress=True)

# [load]
# The bundled EXRs are lossy (DWAB) and hold a handful of slightly negative pixels: set them to 0.
env = read_envmap(ge.bundled_hdri("sunset"), sanitize="zero")
print(env.radiance_linear.shape, env.convention, env.alignment)
print(f"peak radiance {env.radiance_linear.max():.0f}")
print("power per channel (sum of L * solid angle):", ge.total_power(env))
print("mean light direction (world, z up):", ge.mean_light_direction(env))
Image.fromarray(tonemap_preview(env.radiance_linear)).save(OUT / "world.png")

# [pose]
# A Blender camera 2 units from the origin, 30 degrees round from +x, 15 degrees up, looking at the origin.
w2c = ge.orbit_w2c_blender(azimuth_deg=30.0, elevation_deg=15.0, distance=2.0)
print("W2CBlender [R | t]:\n", w2c.matrix)
c2w = w2c.to_c2w_opencv()  # the same camera for NeRF / OpenCV code
print("C2WOpenCV:\n", c2w.matrix)
print("round trip exact:", np.array_equal(c2w.to_w2c_blender().matrix, w2c.matrix))

# [rotate]
cam = ge.rotate_to_camera(env, w2c, height=256)  # [maps, poses, 256, 512, 3], linear radiance
print("rotated:", tuple(cam.shape))
cam_env = ge.EnvironmentMap(radiance_linear=cam[0, 0].numpy(), convention="neural-gaffer-camera")
print("power, camera / world:", ge.total_power(cam_env) / ge.total_power(env))
# The mean light vector rotates with the light: m_cam = R m_world.
print("mean light direction (camera):", ge.mean_light_direction(cam_env))
print("R @ mean light direction (world):", w2c.rotation @ ge.mean_light_direction(env))
Image.fromarray(tonemap_preview(cam_env.radiance_linear)).save(OUT / "camera.png")

# [encode]
enc = ge.encode_lighting(env, w2c)  # default mode: 256x256, area filter, source-peak HDR normaliser
# The released checkpoint expects the authors' pipeline, which they ran on 512x256 maps.
old = ge.encode_lighting(ge.resize_conservative(env, 256), w2c, compat="neural-gaffer")
for e in (enc, old):
    print(
        f"{e.compat:14s} E_L {tuple(e.ldr.shape)}  E_H {tuple(e.hdr.shape)}  E_H max {e.hdr.max():.3f}"
    )
model_input = (
    torch.cat([enc.ldr, enc.hdr], dim=1) * 2 - 1
)  # [B, 6, 256, 256] in [-1, 1] for the VAE
print("model input:", tuple(model_input.shape), float(model_input.min()), float(model_input.max()))
ldr_u8, hdr_u8 = enc.to_uint8()  # round-to-nearest uint8, [B, 256, 256, 3]
Image.fromarray(np.concatenate([ldr_u8[0], hdr_u8[0]], axis=1)).save(OUT / "encodings.png")

# [sh]
coeffs = ge.project_sh(cam_env, order=2)  # [9, 3] real SH of the camera-frame radiance
print("SH coefficients:", coeffs.shape)
# A diffuse sphere as this camera sees it: normals in Blender camera axes (x right, y up, +z to the viewer).
n = 160
y, x = np.mgrid[1 : -1 : n * 1j, -1 : 1 : n * 1j]
inside = x**2 + y**2 < 1
normals = np.stack([x, y, np.sqrt(np.clip(1 - x**2 - y**2, 0, None))], axis=-1)
irr = ge.irradiance(cam_env, normals, order=2)  # [n, n, 3], integral of L max(0, n.w) dw
# Nine coefficients against brute-force quadrature, at the six axis normals:
axes6 = np.concatenate([np.eye(3), -np.eye(3)])
sh9, exact = ge.irradiance(cam_env, axes6), irradiance_brute_force(cam_env, axes6)
print("irradiance, SH order 2 vs quadrature, relative error:", np.abs(sh9 / exact - 1).max(axis=1))
sphere = np.where(inside[..., None], 0.8 / np.pi * np.clip(irr, 0, None), 0.0)  # albedo 0.8
Image.fromarray(
    tonemap_preview(sphere, exposure=1.0 / float(np.percentile(sphere[inside], 99)))
).save(OUT / "sphere.png")

# [augment]
pool = ge.augment_pool(
    env
)  # 2 flips x 8 yaws of 45 degrees: exact pixel permutations (the paper's ~16x)
print(len(pool), "maps:", [spec.tag for spec, _ in pool[:3]], "...")
powers = np.array([ge.total_power(aug) for _, aug in pool])
print("largest power change across the pool:", float(np.abs(powers / powers[0] - 1).max()))
# A yaw in the pool and a turntable spin at rotation time are the same thing (same sign convention):
spun = ge.rotate_to_camera(env, w2c, height=256, spin_deg=45.0)
rolled = ge.rotate_to_camera(ge.yaw_roll(env, 1, 8), w2c, height=256)
print(
    "spin_deg=45 vs yaw_roll(1 of 8), max |difference| / peak:",
    float((spun - rolled).abs().max() / rolled.max()),
)
thumbs = [tonemap_preview(aug.radiance_linear[::4, ::4]) for _, aug in pool]
grid = np.concatenate([np.concatenate(thumbs[r * 4 : r * 4 + 4], axis=1) for r in range(4)], axis=0)
Image.fromarray(grid).save(OUT / "augment.png")
