import json, sys, numpy as np
from PIL import Image
rec, segs = sys.argv[1], sys.argv[2]
W,H=640,480
def rle(runs):
    m=np.zeros(W*H,bool); p=0; fg=False
    for r in runs:
        if fg: m[p:p+r]=True
        p+=r; fg=not fg
    return m
cats={}
n_obj=0
for line in open(segs):
    fr=json.loads(line)
    gt=json.load(open(f"{rec}/{fr['frame']}_gt.json"))
    lab=np.array(Image.open(f"{rec}/{fr['frame']}_mask.png")).reshape(-1)
    gts=[(g['class'], lab==g['id']) for g in gt['instances']]
    n_obj+=len(gts)
    used=set()
    for d in fr['instances']:
        m=rle(d['mask_rle'])
        best=(0,None)
        for j,(c,gm) in enumerate(gts):
            i=(m&gm).sum(); u=(m|gm).sum(); iou=i/u if u else 0
            if iou>best[0]: best=(iou,j)
        iou,j=best
        if iou<0.1: k='no object (distractor/background)'
        elif iou<0.5: k='partial (IoU 0.1-0.5)'
        elif gts[j][0]!=d['class']: k='object, wrong class'
        elif j in used: k='object, right class, second'
        else: k='object, right class, first'; used.add(j)
        if k=='object, right class, first' or True:
            pass
        cats[k]=cats.get(k,0)+1
tot=sum(cats.values())
print(f"{tot} detections, {n_obj} objects")
for k,v in sorted(cats.items()): print(f"  {k}: {v}")
# score quantiles per kind (second pass)
import collections
sc=collections.defaultdict(list)
for line in open(segs):
    fr=json.loads(line)
    gt=json.load(open(f"{rec}/{fr['frame']}_gt.json"))
    lab=np.array(Image.open(f"{rec}/{fr['frame']}_mask.png")).reshape(-1)
    gts=[(g['class'], lab==g['id']) for g in gt['instances']]
    used=set()
    for d in fr['instances']:
        m=rle(d['mask_rle'])
        best=(0,None)
        for j,(c,gm) in enumerate(gts):
            i=(m&gm).sum(); u=(m|gm).sum(); iou=i/u if u else 0
            if iou>best[0]: best=(iou,j)
        iou,j=best
        if iou<0.1: k='none'
        elif iou<0.5: k='partial'
        elif gts[j][0]!=d['class']: k='wrong'
        elif j in used: k='second'
        else: k='first'; used.add(j)
        sc[k].append(d['score'])
for k,v in sc.items():
    v=np.array(v); print(k, len(v), [f"{(v>=t).sum()}" for t in (0.5,0.6,0.7,0.8,0.9,0.95)])
