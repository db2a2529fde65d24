# A Neural 3D Video-like proxy: a forward-facing rig of synchronised cameras filming a
# textured static room (back wall, floor, a table with a vase) and two moving objects (a ball
# rolling across the table, a plate swinging on a curved path), alpha blend, over black.
# Written in both of N3V's layouts with LLFF's poses_bounds.npy:
#   OUT_DIR/frames/camNN/images/0000.png ...   (extracted frames)
#   OUT_DIR/video/camNN.mp4                    (H.264 through ffmpeg, crf 12, yuv420p)
# cam00, held out by splat4d as N3V's authors do, is the rig's middle camera.
# Usage: python3 n3v_like.py SPLAT4D_BINARY OUT_DIR [CAMERAS FRAMES WIDTH]
#   (defaults 12 60 200; standard library and ffmpeg only; under a minute at the defaults)
# Then: splat4d fit --views OUT_DIR/video --out f.json
import json, math, os, random, shutil, struct, subprocess, sys
BIN, OUT = sys.argv[1], sys.argv[2]
CAMS = int(sys.argv[3]) if len(sys.argv) > 3 else 12
FRAMES = int(sys.argv[4]) if len(sys.argv) > 4 else 60
W = int(sys.argv[5]) if len(sys.argv) > 5 else 200
H = (W * 3 // 4) // 2 * 2
os.makedirs(OUT, exist_ok=True)
random.seed(3)
K = []
S = 1e30  # a static kernel's time scale: alive at every time


def tex(p, base):
    a = 0.5 + 0.5 * math.sin(6 * p[0] + 1.3 * math.sin(4 * p[1])) * math.cos(5 * p[1] + 3 * p[2])
    n = random.uniform(-0.06, 0.06)
    return [min(1, max(0, base[c] * (0.55 + 0.6 * a) + n)) for c in range(3)]


def add(p, s, c, t=0.0, st=S, v=(0, 0, 0), o=0.95):
    K.append({"mean": list(p) + [t], "scale": list(s) + [st], "amplitude": c,
              "rotation": [1, 0, 0, 0], "opacity": o, "velocity": list(v)})


def frange(a, b, step):
    x = a
    while x < b:
        yield x
        x += step


sp = 0.08
# The back wall, z = -6 (y up, the cameras look along -z), wide enough to fill every view.
for x in frange(-4.5, 4.5, sp):
    for y in frange(-2.0, 3.2, sp):
        p = [x + random.uniform(-.02, .02), y + random.uniform(-.02, .02), -6.0]
        stripe = int(math.floor(x * 1.5)) % 2
        add(p, [sp * .7, sp * .7, .01], tex(p, [0.8, 0.7, 0.5] if stripe else [0.5, 0.6, 0.8]))
# The floor, y = -1.2, from the wall to in front of the cameras.
for x in frange(-4.5, 4.5, sp):
    for z in frange(-6.0, -0.5, sp):
        p = [x + random.uniform(-.02, .02), -1.2, z + random.uniform(-.02, .02)]
        chk = (int(math.floor(x * 2)) + int(math.floor(z * 2))) % 2
        add(p, [sp * .7, .01, sp * .7], tex(p, [0.6, 0.45, 0.3] if chk else [0.35, 0.3, 0.25]))
# A table top (y = -0.4, x in [-1.2, 1.2], z in [-4, -2.8]) and a vase on it.
for x in frange(-1.2, 1.2, 0.05):
    for z in frange(-4.0, -2.8, 0.05):
        p = [x, -0.4, z]
        add(p, [.035, .01, .035], tex(p, [0.9, 0.85, 0.8]))
for i in range(2500):
    u = random.uniform(0, 2 * math.pi); h = random.uniform(0, 0.7)
    r = 0.12 + 0.08 * math.sin(h * 4.5)
    p = [-0.7 + r * math.cos(u), -0.4 + h, -3.5 + r * math.sin(u)]
    add(p, [.02, .02, .02], [0.2, 0.5 + 0.3 * math.sin(8 * u), 0.3], o=0.98)
# A ball rolling across the table at constant speed (one kernel set with a velocity).
for i in range(1500):
    z = random.uniform(-1, 1); th = random.uniform(0, 2 * math.pi); r = math.sqrt(1 - z * z)
    n = [r * math.cos(th), r * math.sin(th), z]
    p = [-0.6 + 0.15 * n[0], -0.25 + 0.15 * n[1], -3.1 + 0.15 * n[2]]
    c = [0.95, 0.3, 0.2] if (math.floor(4 * th / math.pi) + math.floor(3 * z)) % 2 else [0.95, 0.9, 0.3]
    add(p, [.02, .02, .02], c, t=0.0, v=(1.2, 0, 0), o=0.98)
# A plate swinging on an arc above the table, sampled at T times (as import-gltf samples).
T = 30
for k in range(T):
    t = k / (T - 1); ang = 1.6 * math.sin(2 * math.pi * t)
    centre = [0.9 * math.sin(ang), 0.9 - 0.5 * math.cos(ang), -3.3]
    vel = [0.9 * math.cos(ang) * 1.6 * 2 * math.pi * math.cos(2 * math.pi * t),
           0.5 * math.sin(ang) * 1.6 * 2 * math.pi * math.cos(2 * math.pi * t), 0]
    for i in range(250):
        a, b = random.uniform(-1, 1), random.uniform(-1, 1)
        p = [centre[0] + 0.25 * a, centre[1] + 0.18 * b, centre[2]]
        c = [0.2, 0.3, 0.9] if (a * b > 0) else [0.9, 0.9, 0.9]
        add(p, [.03, .03, .01], c, t=t, st=0.5 / (T - 1), v=vel, o=0.98)
json.dump({"blend": "alpha", "kernels": K, "background": [0, 0, 0]}, open(OUT + '/scene.json', 'w'))
print(len(K), "kernels", file=sys.stderr)


def sub(a, b): return [a[i] - b[i] for i in range(3)]
def cross(a, b): return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
def unit(a):
    n = math.sqrt(sum(v * v for v in a)); return [v / n for v in a]


# The rig: a slightly curved wall of cameras 1.6 wide and 0.6 high at z = 0, each aimed at
# a point 4.5 in front of the rig's middle (N3V's cameras converge gently); cam00 in the middle.
positions = [[0.0, 0.0]]
cols = max(2, round(math.sqrt(CAMS * 8 / 3)))
rows = max(1, math.ceil((CAMS - 1) / cols))
grid = [[-0.8 + 1.6 * i / (cols - 1), (0.3 - 0.6 * j / (rows - 1)) if rows > 1 else 0.15]
        for j in range(rows) for i in range(cols)]
grid.sort(key=lambda q: (abs(q[0]) < 0.15 and abs(q[1]) < 0.1, q[1], q[0]))
positions += grid[:CAMS - 1]
fy = H / 2 / math.tan(math.radians(50) / 2)
cams, rows_npy = [], []
for (x, y) in positions:
    eye = [x, y + 0.2, 0.05 * (x * x + y * y)]
    f = unit(sub([0.3 * x, 0.0, -4.5], eye))
    r = unit(cross(f, [0, 1, 0])); d = cross(f, r)  # OpenCV: x right, y down, z forward
    t = [-sum([r, d, f][i][k] * eye[k] for k in range(3)) for i in range(3)]
    w2c = [[*r, t[0]], [*d, t[1]], [*f, t[2]], [0, 0, 0, 1]]
    cams.append({"width": W, "height": H, "fx": fy, "fy": fy, "cx": W / 2, "cy": H / 2,
                 "world_to_camera": w2c})
    # LLFF's columns are [down, right, back] camera to world: [d, r, -f], then the centre, hwf.
    hwf = [H, W, fy]
    for i in range(3):
        rows_npy += [d[i], r[i], -f[i], eye[i], hwf[i]]
    rows_npy += [1.5, 9.0]
header = "{'descr': '<f8', 'fortran_order': False, 'shape': (%d, 17), }" % len(cams)
header += ' ' * (63 - (11 + len(header)) % 64) + '\n'
npy = b'\x93NUMPY\x01\x00' + struct.pack('<H', len(header)) + header.encode() + struct.pack('<%dd' % len(rows_npy), *rows_npy)
for layout in ('frames', 'video'):
    os.makedirs(OUT + '/' + layout, exist_ok=True)
    open(OUT + '/' + layout + '/poses_bounds.npy', 'wb').write(npy)
for c, cam in enumerate(cams):
    folder = OUT + '/frames/cam%02d/images' % c
    os.makedirs(folder, exist_ok=True)
    json.dump(cam, open(OUT + '/cam%02d.json' % c, 'w'))
    # One `video --path` per camera: the frames are the PNGs `render` would write.
    path = [{"camera": cam, "time": k / (FRAMES - 1)} for k in range(FRAMES)]
    json.dump(path, open(OUT + '/path%02d.json' % c, 'w'))
    subprocess.run([BIN, 'video', '--scene', OUT + '/scene.json', '--path', OUT + '/path%02d.json' % c,
                    '--out', OUT + '/render', '--no-gif', '--no-mp4'], check=True, capture_output=True)
    for k in range(FRAMES):
        os.replace(OUT + '/render/path%02d/frame_%04d.png' % (c, k), folder + '/%04d.png' % k)
    subprocess.run(['ffmpeg', '-v', 'error', '-y', '-framerate', '30', '-i', folder + '/%04d.png',
                    '-c:v', 'libx264', '-crf', '12', '-pix_fmt', 'yuv420p', OUT + '/video/cam%02d.mp4' % c],
                   check=True)
shutil.rmtree(OUT + '/render', ignore_errors=True)
print(len(cams), "cameras,", FRAMES, "frames of", W, "x", H, file=sys.stderr)
