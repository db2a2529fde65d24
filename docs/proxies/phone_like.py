# A phone-capture proxy: a static textured room with two objects, 50 portrait photos
# (1080x1920) on an arc, rendered as pinhole images by splat4d, then OPENCV-distorted
# (k1 k2 p1 p2) and saved as JPEG, with a nerfstudio transforms.json that writes its sizes as
# floats, as ns-process-data does.
# Usage: python3 phone_like.py SPLAT4D_BINARY OUT_DIR   (needs numpy and pillow; ~2 minutes)
# The capture is OUT_DIR/cap: splat4d fit --views OUT_DIR/cap --downscale 8 --out f.json
import json, math, random, subprocess, os, sys
BIN, OUT = sys.argv[1], sys.argv[2]
os.makedirs(OUT, exist_ok=True)
import numpy as np
from PIL import Image
random.seed(2); rng=np.random.default_rng(2)
K=[]
def tex(p, base):
    a=0.5+0.5*math.sin(7*p[0]+1.3*math.sin(5*p[2]))*math.cos(6*p[1]+4*p[2])
    n=random.uniform(-0.08,0.08)
    return [min(1,max(0,base[0]*(0.6+0.5*a)+n)),min(1,max(0,base[1]*(0.6+0.5*a)+n)),min(1,max(0,base[2]*(0.7+0.3*a)+n))]
S=1e30
def add(p,s,c,rot=[1,0,0,0],o=0.95):
    K.append({"mean":list(p)+[0.0],"scale":list(s)+[S],"amplitude":c,"rotation":rot,"opacity":o,"velocity":[0,0,0]})
sp=0.07
# floor y=+0.5 (OpenCV-ish world: y down? we use y up: floor at y=-0.5)
for x in np.arange(-3,3,sp):
    for z in np.arange(-3,3,sp):
        p=[x+random.uniform(-.02,.02),-0.5,z+random.uniform(-.02,.02)]
        chk=(int(math.floor(x*2))+int(math.floor(z*2)))%2
        add(p,[sp*0.7,0.01,sp*0.7],tex(p,[0.7,0.6,0.45] if chk else [0.45,0.35,0.3]),[0.7071,0,0,0.7071] if False else [1,0,0,0])
# walls
for w in range(4):
    for u in np.arange(-3,3,sp):
        for y in np.arange(-0.5,2.5,sp):
            if w==0: p=[u,y,-3]; s=[sp*0.7,sp*0.7,0.01]
            if w==1: p=[u,y,3]; s=[sp*0.7,sp*0.7,0.01]
            if w==2: p=[-3,y,u]; s=[0.01,sp*0.7,sp*0.7]
            if w==3: p=[3,y,u]; s=[0.01,sp*0.7,sp*0.7]
            base=[[0.3,0.5,0.8],[0.8,0.4,0.3],[0.4,0.7,0.4],[0.8,0.8,0.5]][w]
            add(p,s,tex(p,base))
# object: textured ellipsoid on the floor, and a box
for i in range(6000):
    z=random.uniform(-1,1); th=random.uniform(0,2*math.pi); r=math.sqrt(1-z*z)
    p=[0.35*r*math.cos(th), -0.1+0.4*z, 0.3*r*math.sin(th)]
    add(p,[0.025,0.025,0.025],tex(p,[0.9,0.3,0.6]),o=0.98)
for i in range(3000):
    f=random.randrange(6); a,b=random.uniform(-1,1),random.uniform(-1,1)
    q=[[1,a,b],[-1,a,b],[a,1,b],[a,-1,b],[a,b,1],[a,b,-1]][f]
    p=[0.8+0.2*q[0],-0.3+0.2*q[1],0.3+0.2*q[2]]
    add(p,[0.02,0.02,0.02],tex(p,[0.2,0.8,0.9]) if (f%2) else [0.95,0.9,0.2],o=0.98)
json.dump({"blend":"alpha","kernels":K,"background":[0,0,0]},open(OUT+'/room.json','w'))
print(len(K), file=sys.stderr)
W,H=1080,1920; fy=H/2/math.tan(math.radians(60)/2); fx=fy; cx=W/2+3.5; cy=H/2-6.0
dist=dict(k1=0.0578421,k2=-0.0921,p1=0.00041,p2=-0.00072)
def look_at(eye,target,up=(0,1,0)):
    f=np.array(target)-np.array(eye); f/=np.linalg.norm(f)
    r=np.cross(f,up); r/=np.linalg.norm(r); d=np.cross(f,r)  # opencv: x right, y down, z forward
    R=np.stack([r,d,f]); t=-R@np.array(eye); return R,t
os.makedirs(OUT+'/cap/images',exist_ok=True); os.makedirs(OUT+'/pin',exist_ok=True)
frames=[]
N=50
for k in range(N):
    ang=math.radians(-100+200*k/(N-1)); rad=1.9+0.15*math.sin(3*ang)
    eye=[rad*math.sin(ang), 0.35+0.1*math.cos(2*ang), rad*math.cos(ang)]
    R,t=look_at(eye,[0.2+0.1*math.sin(ang),-0.2,0.1])
    w2c=np.eye(4); w2c[:3,:3]=R; w2c[:3,3]=t
    cam={"width":W,"height":H,"fx":fx,"fy":fy,"cx":cx,"cy":cy,"world_to_camera":w2c.tolist()}
    json.dump(cam,open(OUT+'/pin/cam_%02d.json'%k,'w'))
    subprocess.run([BIN,'render','--scene',OUT+'/room.json','--camera',OUT+'/pin/cam_%02d.json'%k,'--time','0','--out',OUT+'/pin/pin_%02d.png'%k],check=True,capture_output=True)
    P=np.asarray(Image.open(OUT+'/pin/pin_%02d.png'%k).convert('RGB')).astype(np.float32)
    # distorted pixel centres -> normalised -> undistort (fixed point) -> pinhole pixel -> bilinear
    jj,ii=np.mgrid[0:H,0:W]; xd=(ii+0.5-cx)/fx; yd=(jj+0.5-cy)/fy
    x,y=xd.copy(),yd.copy()
    for _ in range(30):
        r2=x*x+y*y; rad_=1+dist['k1']*r2+dist['k2']*r2*r2
        dx=2*dist['p1']*x*y+dist['p2']*(r2+2*x*x); dy=dist['p1']*(r2+2*y*y)+2*dist['p2']*x*y
        x=(xd-dx)/rad_; y=(yd-dy)/rad_
    u=x*fx+cx-0.5; v=y*fy+cy-0.5
    u=np.clip(u,0,W-1.001); v=np.clip(v,0,H-1.001); i0=np.floor(u).astype(int); j0=np.floor(v).astype(int); fu=(u-i0)[...,None]; fv=(v-j0)[...,None]
    D=(P[j0,i0]*(1-fu)+P[j0,i0+1]*fu)*(1-fv)+(P[j0+1,i0]*(1-fu)+P[j0+1,i0+1]*fu)*fv
    Image.fromarray(np.clip(D+0.5,0,255).astype(np.uint8)).save(OUT+'/cap/images/frame_%05d.jpg'%(k+1),quality=92)
    c2w=np.linalg.inv(w2c); c2w[:3,1]*=-1; c2w[:3,2]*=-1  # OpenCV -> OpenGL
    frames.append({"file_path":"images/frame_%05d.jpg"%(k+1),"transform_matrix":c2w.tolist(),"colmap_im_id":k+1})
tr={"w":float(W),"h":float(H),"fl_x":fx,"fl_y":fy,"cx":cx,"cy":cy,**dist,"camera_model":"OPENCV","frames":frames}
json.dump(tr,open(OUT+'/cap/transforms.json','w'),indent=1)
