# A DSLR-capture proxy in COLMAP form: a textured figurine (an ellipsoid and a box) on a
# textured table in front of a textured backdrop, 23 photos (600x400, PNG) on a narrow
# 27-degree arc, rendered by splat4d as pinhole images. The sparse model
# (sparse/0/{cameras,images,points3D}.txt, PINHOLE) has a point cloud on the figurine ONLY,
# as COLMAP's often is: the table and the backdrop behind it have no point.
# Usage: python3 dslr_like.py SPLAT4D_BINARY OUT_DIR [plain|far]   (needs numpy; ~1 minute)
# `plain`: the backdrop is a plain painted wall instead (a soft shading), as a room's walls
# are. `far`: the patterned backdrop is 13 times as far and as large (z = -28.6), beyond
# the depths a plane sweep tries, as distant scenery is. Both draw the same random numbers
# as the default, so the figurine and its cloud are the default's.
# The capture is OUT_DIR/cap: splat4d fit --views OUT_DIR/cap --downscale 4 --out f.json
# (every 8th photo, 0, 8, 16, is held out: 20 training views).
import json, math, random, subprocess, os, sys
import numpy as np
BIN, OUT = sys.argv[1], sys.argv[2]
MODE = sys.argv[3] if len(sys.argv) > 3 else ''
if MODE not in ('', 'plain', 'far'):
    sys.exit("dslr_like.py: the third argument is `plain` or `far`, not `%s`" % MODE)
PLAIN, FAR = MODE == 'plain', MODE == 'far'
os.makedirs(OUT, exist_ok=True)
random.seed(3); rng = np.random.default_rng(3)
K = []
def tex(p, base, f=12.0):
    a = 0.5 + 0.5 * math.sin(f * p[0] + 1.7 * math.sin(6 * p[2] + 2 * p[1])) * math.cos(f * 0.8 * p[1] + 5 * p[2])
    n = random.uniform(-0.06, 0.06)
    return [min(1, max(0, base[c] * (0.55 + 0.6 * a) + n)) for c in range(3)]
S = 1e30
def add(p, s, c, o=0.97):
    K.append({"mean": list(map(float, p)) + [0.0], "scale": list(map(float, s)) + [S], "amplitude": c,
              "rotation": [1, 0, 0, 0], "opacity": o, "velocity": [0, 0, 0]})
# World: y up, the table top at y = -0.5, the backdrop at z = -2.2, the cameras at z > 0.
sp = 0.035
for x in np.arange(-3.5, 3.5, sp):          # table (wood-like stripes and a paper sheet)
    for z in np.arange(-2.2, 3.0, sp):
        p = [x + random.uniform(-.01, .01), -0.5, z + random.uniform(-.01, .01)]
        paper = -1.1 < p[0] < -0.3 and -0.9 < p[2] < -0.2
        base = [0.92, 0.92, 0.88] if paper else ([0.65, 0.45, 0.3] if int(math.floor(p[0] * 3 + 0.3 * math.sin(4 * p[2]))) % 2 else [0.5, 0.34, 0.22])
        add(p, [sp * 0.5, 0.006, sp * 0.5], tex(p, base, 40.0 if paper else 24.0))
G = 13.0 if FAR else 1.0                    # the far backdrop: 13 times as far, as large
for x in np.arange(-4.0, 4.0, sp):          # backdrop (a patterned cloth)
    for y in np.arange(-0.5, 3.0, sp):
        p = [x + random.uniform(-.01, .01), y + random.uniform(-.01, .01), -2.2]
        if FAR:
            chk = (int(math.floor(x * 2.5)) + int(math.floor(y * 2.5))) % 2
            c = tex(p, [0.3, 0.45, 0.75] if chk else [0.75, 0.7, 0.4], 24.0)
            add([G * p[0], G * (p[1] + 0.5) - 8.5, G * p[2]], [G * sp * 0.5, G * sp * 0.5, 0.08], c)
            continue
        if PLAIN:  # a soft light from the upper left, nothing to match between views
            random.uniform(-0.06, 0.06)  # the draw tex() makes, to keep the sequence in step
            shade = 0.8 + 0.12 * math.tanh(0.5 * (y - 1.0) - 0.3 * x)
            add(p, [sp, sp, 0.006], [0.86 * shade, 0.82 * shade, 0.74 * shade])
            continue
        chk = (int(math.floor(x * 2.5)) + int(math.floor(y * 2.5))) % 2
        add(p, [sp * 0.5, sp * 0.5, 0.006], tex(p, [0.3, 0.45, 0.75] if chk else [0.75, 0.7, 0.4], 24.0))
obj = []                                     # the figurine: surface kernels, their points kept
for i in range(9000):
    z = random.uniform(-1, 1); th = random.uniform(0, 2 * math.pi); r = math.sqrt(1 - z * z)
    p = [0.28 * r * math.cos(th), -0.1 + 0.4 * z * 0.98, 0.25 * r * math.sin(th)]
    c = tex(p, [0.9, 0.35, 0.55], 18.0); add(p, [0.014] * 3, c, 0.99); obj.append((p, c))
for i in range(4000):
    f = random.randrange(6); a, b = random.uniform(-1, 1), random.uniform(-1, 1)
    q = [[1, a, b], [-1, a, b], [a, 1, b], [a, -1, b], [a, b, 1], [a, b, -1]][f]
    p = [0.55 + 0.15 * q[0], -0.35 + 0.15 * q[1], 0.25 + 0.15 * q[2]]
    c = tex(p, [0.2, 0.8, 0.9], 20.0) if f % 2 else [0.95, 0.85, 0.2]; add(p, [0.012] * 3, c, 0.99); obj.append((p, c))
json.dump({"blend": "alpha", "kernels": K, "background": [0, 0, 0]}, open(OUT + '/scene.json', 'w'))
print(len(K), "kernels", file=sys.stderr)
W, H = 600, 400; fx = fy = W / 2 / math.tan(math.radians(50) / 2); cx, cy = W / 2, H / 2
def look_at(eye, target, up=(0, 1, 0)):
    f = np.array(target) - np.array(eye); f /= np.linalg.norm(f)
    r = np.cross(f, up); r /= np.linalg.norm(r); d = np.cross(f, r)  # OpenCV: x right, y down, z forward
    R = np.stack([r, d, f]); t = -R @ np.array(eye); return R, t
def quat(R):  # rotation matrix -> (w, x, y, z)
    w = math.sqrt(max(0, 1 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    return [w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)]
cap = OUT + '/cap'; os.makedirs(cap + '/images', exist_ok=True); os.makedirs(cap + '/sparse/0', exist_ok=True)
os.makedirs(OUT + '/cams', exist_ok=True)
N = 23; lines = []
for k in range(N):
    ang = math.radians(-13.5 + 27 * k / (N - 1)); rad = 2.3 + 0.05 * math.sin(5 * ang)
    eye = [rad * math.sin(ang), 0.55 + 0.04 * math.cos(3 * ang), rad * math.cos(ang)]
    R, t = look_at(eye, [0.15, -0.3, 0.0])
    w2c = np.eye(4); w2c[:3, :3] = R; w2c[:3, 3] = t
    json.dump({"width": W, "height": H, "fx": fx, "fy": fy, "cx": cx, "cy": cy, "world_to_camera": w2c.tolist()},
              open(OUT + '/cams/cam_%02d.json' % k, 'w'))
    name = 'DSC_%04d.png' % (k + 1)
    subprocess.run([BIN, 'render', '--scene', OUT + '/scene.json', '--camera', OUT + '/cams/cam_%02d.json' % k,
                    '--time', '0', '--out', cap + '/images/' + name], check=True, capture_output=True)
    q = quat(R)
    lines.append('%d %.12f %.12f %.12f %.12f %.12f %.12f %.12f 1 %s\n\n' % (k + 1, *q, *t, name))
open(cap + '/sparse/0/cameras.txt', 'w').write('1 PINHOLE %d %d %.9f %.9f %.9f %.9f\n' % (W, H, fx, fy, cx, cy))
open(cap + '/sparse/0/images.txt', 'w').write(''.join(lines))
with open(cap + '/sparse/0/points3D.txt', 'w') as f:  # 2000 noisy points on the figurine only
    for i, (p, c) in enumerate(random.sample(obj, 2000)):
        p = [v + rng.normal(0, 0.004) for v in p]
        f.write('%d %.6f %.6f %.6f %d %d %d 0.5\n' % (i + 1, *p, *[round(255 * v) for v in c]))
