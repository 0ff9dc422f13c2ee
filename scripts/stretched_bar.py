#!/usr/bin/env python3
"""The second stretch case of issue 14 item 2 (README, meshmatch): a bar of square section
(half-width 0.5, x in [0, 4], 257 rings of 256 vertices, fan caps) with the capsule pair's black
and white ring stripes (period 0.5) as COLOR_0, and the same bar with x in [2, 4] stretched to
[2, 6]. Writes SRC.glb and TGT.glb. With --round, the capsule pair of `retex bench --method
meshmatch` instead (circular section of radius 0.5, 256 around, hemispherical caps of 8 rings:
the vertices and triangles of `primitives::capsule`, 69,378 vertices); --round32 the same with
32 cap rings and each quad split along its other diagonal (81,666 vertices), the third file of
the README's HKS-units sweep. Usage: stretched_bar.py [--round | --round32] SRC.glb TGT.glb"""
import numpy as np, json, struct, sys
def stripe(x):
    s=np.sin(2*np.pi*x/0.5); return 0.05+0.85*(0.5+0.5*np.tanh(4*s))
def stretch(x): return np.where(x<=2, x, x+(np.minimum(x,4)-2))
def square_loop(n_side):
    # points around a square of half-width 0.5, counter-clockwise, 4*n_side points
    pts=[]
    for side in range(4):
        for i in range(n_side):
            t=-0.5+i/n_side
            y,z={0:(0.5,t),1:(-t,0.5),2:(-0.5,-t),3:(t,-0.5)}[side]
            pts.append((y,z))
    return np.array(pts)
def round_capsule(fx, around=256, rings=257, cap_rings=8, other_split=False):
    # The vertices and triangles of `primitives::capsule`, in its order: left pole, rings from
    # left to right, right pole.
    ang=2*np.pi*np.arange(around)/around
    q=lambda k: np.pi/2*k/cap_rings
    secs=[(-0.5*np.cos(q(k)),0.5*np.sin(q(k))) for k in range(1,cap_rings)]
    secs+=[(x,0.5) for x in np.linspace(0,4,rings)]
    secs+=[(4+0.5*np.cos(q(k)),0.5*np.sin(q(k))) for k in range(cap_rings-1,0,-1)]
    P=[(fx(-0.5),0,0)]
    for x,r in secs:
        for a in ang: P.append((fx(x),r*np.cos(a),r*np.sin(a)))
    P.append((fx(4.5),0,0))
    n=len(secs); m=around; last=len(P)-1
    at=lambda ring,j: 1+ring*m+j%m
    F=[(0,at(0,j+1),at(0,j)) for j in range(m)]
    for i in range(n-1):
        for j in range(m):
            a,b,c,d=at(i,j),at(i,j+1),at(i+1,j),at(i+1,j+1)
            F+=[(a,b,c),(b,d,c)] if other_split else [(a,b,d),(a,d,c)]
    F+=[(last,at(n-1,j),at(n-1,j+1)) for j in range(m)]
    return np.array(P,np.float32),np.array(F,np.uint32)
def box(fx, n_side=64, rings=257):
    loop=square_loop(n_side); m=len(loop)
    xs=np.linspace(0,4,rings)
    P=[];F=[]
    for i,x in enumerate(xs):
        for (y,z) in loop: P.append((fx(x),y,z))
    for i in range(rings-1):
        for j in range(m):
            a=i*m+j;b=i*m+(j+1)%m;c=(i+1)*m+j;d=(i+1)*m+(j+1)%m
            F+= [(a,c,b),(b,c,d)]
    # caps: centre fans
    c0=len(P);P.append((fx(0.0),0,0)); c1=len(P);P.append((fx(4.0),0,0))
    last=(rings-1)*m
    for j in range(m):
        F.append((c0,j,(j+1)%m)); F.append((c1,last+(j+1)%m,last+j))
    return np.array(P,np.float32),np.array(F,np.uint32)
def glb(P,F,C,path):
    blobs=[];views=[];accs=[];off=0
    def add(arr,target,typ,comp,minmax=False):
        nonlocal off
        b=arr.tobytes(); pad=(-len(b))%4
        views.append({"buffer":0,"byteOffset":off,"byteLength":len(b),"target":target})
        a={"bufferView":len(views)-1,"componentType":comp,"count":len(arr) if arr.ndim>1 else arr.size,"type":typ}
        if minmax: a["min"]=arr.min(0).tolist();a["max"]=arr.max(0).tolist()
        accs.append(a); blobs.append(b+b'\0'*pad); off+=len(b)+pad; return len(accs)-1
    attrs={"POSITION":add(P,34962,"VEC3",5126,True)}
    if C is not None: attrs["COLOR_0"]=add(C,34962,"VEC4",5126)
    idx=add(F.reshape(-1),34963,"SCALAR",5125)
    js={"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],
        "meshes":[{"primitives":[{"attributes":attrs,"indices":idx}]}],
        "accessors":accs,"bufferViews":views,"buffers":[{"byteLength":off}]}
    j=json.dumps(js).encode(); j+=b' '*((-len(j))%4); binb=b''.join(blobs)
    out=struct.pack('<III',0x46546C67,2,12+8+len(j)+8+len(binb))+struct.pack('<II',len(j),0x4E4F534A)+j+struct.pack('<II',len(binb),0x004E4942)+binb
    open(path,'wb').write(out)
args=[a for a in sys.argv[1:] if a not in ('--round','--round32')]
make=box
if '--round' in sys.argv: make=round_capsule
if '--round32' in sys.argv: make=lambda fx: round_capsule(fx, cap_rings=32, other_split=True)
P,F=make(lambda x:x); g=stripe(P[:,0]).astype(np.float32)
C=np.stack([g,g,g,np.ones_like(g)],1).astype(np.float32)
glb(P,F,C,args[0])
P2,F2=make(stretch); glb(P2,F2,None,args[1])
print(len(P),len(F))
