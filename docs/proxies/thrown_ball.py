# A ball thrown under gravity over a textured floor (SPEC §9): 400 kernels on a sphere that share
# one velocity and one acceleration and live the whole time, so that the ball's centre follows a
# parabola (x from -0.6 to 0.6, height -0.2 -> 0.2 -> -0.2 over t in [0, 1]); 1500 flat kernels on
# a checkered floor below it. Alpha blend.
# Usage: python3 thrown_ball.py OUT.json, then
#   splat4d dataset --scene OUT.json --views 12 --times 20 --size 64x64 --out DIR
# Needs only the standard library.
import sys
import json, math, random
random.seed(3)
K = []
# The ball: radius 0.25, centred at (0, 0.2, 0) at t = 0.5, striped by longitude.
for i in range(400):
    z = random.uniform(-1, 1); th = random.uniform(0, 2 * math.pi); r = math.sqrt(1 - z * z)
    n = [r * math.cos(th), r * math.sin(th), z]
    p = [0.25 * n[0], 0.2 + 0.25 * n[1], 0.25 * n[2]]
    c = [0.95, 0.9, 0.8] if math.floor(3 * th / math.pi) % 2 == 0 else [0.9, 0.3, 0.1]
    K.append({"mean": p + [0.5], "scale": [0.04, 0.04, 0.04, 50.0], "amplitude": c,
              "velocity": [1.2, 0.0, 0.0], "acceleration": [0.0, -3.2, 0.0], "opacity": 0.95})
# The floor: y = -0.6, x and z in [-1.2, 1.2], checkered in cells of 0.4.
for i in range(1500):
    x = random.uniform(-1.2, 1.2); z = random.uniform(-1.2, 1.2)
    c = [0.2, 0.5, 0.3] if (math.floor(x / 0.4) + math.floor(z / 0.4)) % 2 == 0 else [0.5, 0.4, 0.2]
    K.append({"mean": [x, -0.6, z, 0.5], "scale": [0.06, 0.01, 0.06, 50.0], "amplitude": c,
              "velocity": [0, 0, 0], "opacity": 0.95})
json.dump({"blend": "alpha", "kernels": K}, open(sys.argv[1], "w"))
print(len(K))
