#!/usr/bin/env python3
"""Stripe period of a MeshMatch output on the striped capsule pair of `retex bench --method
meshmatch` (README, issue 14 item 2): grey crossings counted along 16 lines of the cylinder
(x axis, radius 0.5) in the unstretched window x in [0.2, 1.8] and the stretched one [2.4, 5.6],
the median line reported as a multiple of the source period 0.5 (per line: twice the distance
between the first and last interpolated crossing over the crossings between them), and `rings`:
the fraction of crossings that the next line (1/16 turn on) crosses within a quarter period too
(about 1 for rings; a hook, U-turn or swirl lowers it, which the period cannot see). Needs COLOR_0 in the output
(`"output": {"vertex_colors": true}`). Usage: stripe_period.py OUT.glb"""
import json,struct,sys,numpy as np
def load(path):
    b=open(path,'rb').read()
    jl=struct.unpack('<I',b[12:16])[0]; js=json.loads(b[20:20+jl]); off=20+jl
    bl=struct.unpack('<I',b[off:off+4])[0]; bin_=b[off+8:off+8+bl]
    prim=js['meshes'][0]['primitives'][0]
    def acc(i):
        a=js['accessors'][i]; bv=js['bufferViews'][a['bufferView']]
        comp={5126:np.float32,5121:np.uint8,5123:np.uint16,5125:np.uint32}[a['componentType']]
        n={'SCALAR':1,'VEC2':2,'VEC3':3,'VEC4':4}[a['type']]
        start=bv.get('byteOffset',0)+a.get('byteOffset',0)
        stride=bv.get('byteStride',0) or n*np.dtype(comp).itemsize
        raw=np.frombuffer(bin_,dtype=np.uint8,count=stride*a['count'],offset=start).reshape(a['count'],stride)
        arr=raw[:,:n*np.dtype(comp).itemsize].copy().view(comp).reshape(a['count'],n).astype(np.float64)
        if a.get('normalized'): arr/=np.iinfo(comp).max
        return arr
    P=acc(prim['attributes']['POSITION']); C=acc(prim['attributes']['COLOR_0'])
    return P,C[:,:3].mean(1)
def crossing_points(x,g,lo,hi,t=None):
    """Interpolated positions of the grey level t (default: the line's mid grey in the window)
    crossed along one line in [lo, hi]."""
    m=(x>=lo)&(x<=hi); xs=x[m]; gs=g[m]; o=np.argsort(xs); xs,gs=xs[o],gs[o]
    if t is None: t=0.5*(gs.max()+gs.min())
    s=gs>t; i=np.nonzero(s[1:]!=s[:-1])[0]
    return xs[i]+(t-gs[i])/(gs[i+1]-gs[i])*(xs[i+1]-xs[i])
def crossings(x,g,lo,hi):
    """Stripe period on one line: grey threshold crossings (linearly interpolated) in [lo, hi],
    2 x (last - first) / (count - 1), so the window's ends do not quantize it."""
    xc=crossing_points(x,g,lo,hi)
    if len(xc)<2: return 2*(hi-lo)
    return 2*(xc[-1]-xc[0])/(len(xc)-1)
P,g=load(sys.argv[1])
r=np.hypot(P[:,1],P[:,2]); ang=np.arctan2(P[:,2],P[:,1])
res={'unstretched':[], 'stretched':[]}
for k in range(16):
    th=-np.pi+2*np.pi*k/16
    d=np.abs((ang-th+np.pi)%(2*np.pi)-np.pi)
    m=(d<0.02)&(r>0.45)
    for name,(lo,hi) in {'unstretched':(0.2,1.8),'stretched':(2.4,5.6)}.items():
        res[name].append(crossings(P[m,0],g[m],lo,hi)/0.5)
# Ring consistency: rings cross every line at the same x, so each crossing on one line has one
# on the next line (1/16 turn away) within a quarter period (0.125); a stripe bent into a hook,
# a U-turn or a swirl does not. The fraction of crossings with such a partner, both windows.
t=0.5*(g.max()+g.min()); lines=[]
for k in range(16):
    th=-np.pi+2*np.pi*k/16
    d=np.abs((ang-th+np.pi)%(2*np.pi)-np.pi); m=(d<0.02)&(r>0.45)
    lines.append(np.concatenate([crossing_points(P[m,0],g[m],lo,hi,t) for lo,hi in ((0.2,1.8),(2.4,5.6))]))
paired=total=0
for k in range(16):
    a,b=lines[k],lines[(k+1)%16]
    for c in a:
        total+=1; paired+=bool(len(b)) and np.abs(b-c).min()<0.125
out={k:round(float(np.median(v)),2) for k,v in res.items()}
out['rings']=round(float(paired)/max(total,1),3)
print(sys.argv[1], out)
