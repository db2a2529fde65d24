# A D-NeRF-like proxy scene: a textured body, a head bobbing up and down and an arm turning
# about its shoulder (both sampled at 25 times, as `import-gltf` samples motion), alpha blend.
# Usage: python3 dnerf_like.py OUT.json, then
#   splat4d dataset --scene OUT.json --views 100 --times 100 --monocular --size 100x100 --out DIR
# (one camera per time, as D-NeRF's captures are). Needs only the standard library.
import sys
import json, math, random
random.seed(1)
K=[]
def colour(p):
    a=0.5+0.5*math.sin(9*p[0])*math.cos(7*p[1]+3*p[2])
    b=0.5+0.5*math.sin(13*p[2]+2*p[0])
    return [0.15+0.8*a, 0.2+0.6*b*a, 0.9-0.7*b]
# body: ellipsoid surface
for i in range(5000):
    z=random.uniform(-1,1); th=random.uniform(0,2*math.pi); r=math.sqrt(1-z*z)
    n=[r*math.cos(th), r*math.sin(th), z]
    p=[0.35*n[0], 0.25*n[1], 0.5*n[2]]
    K.append({"mean":p+[0.5],"scale":[0.025,0.025,0.025,5.0],"amplitude":colour(p),"velocity":[0,0,0],"opacity":0.9})
# head: sphere that moves up and down non-linearly
T=25
for k in range(T):
    t=k/(T-1); dz=0.12*math.sin(2*math.pi*t)
    for i in range(300):
        z=random.uniform(-1,1); th=random.uniform(0,2*math.pi); r=math.sqrt(1-z*z)
        p=[0.15*r*math.cos(th), 0.15*r*math.sin(th), 0.68+0.15*z+dz]
        c=[0.95,0.8,0.3] if (math.floor(6*th/math.pi)%2==0) else [0.3,0.2,0.1]
        K.append({"mean":p+[t],"scale":[0.03,0.03,0.03,0.5/(T-1)],"amplitude":c,"velocity":[0,0,0.12*2*math.pi*math.cos(2*math.pi*t)],"opacity":0.9})
# arm ("shovel"): a plate turning about the x axis around the shoulder
for k in range(T):
    t=k/(T-1); ang=-0.3+2.2*t
    for i in range(500):
        u=random.uniform(0,0.7); v=random.uniform(-0.08,0.08)
        # plate along direction (0, cos, sin) from shoulder
        d=[0, math.cos(ang), math.sin(ang)]
        p=[0.38+v, 0.15+u*d[1], 0.2+u*d[2]]
        w=2.2/1.0  # angular speed
        vel=[0, -u*math.sin(ang)*w, u*math.cos(ang)*w]
        c=[0.9,0.9,0.9] if u>0.5 else [0.8,0.1,0.1]
        K.append({"mean":p+[t],"scale":[0.03,0.03,0.01,0.5/(T-1)],"amplitude":c,"velocity":vel,"opacity":0.95})
json.dump({"blend":"alpha","kernels":K,"background":[0,0,0]},open(sys.argv[1],'w'))
print(len(K))
