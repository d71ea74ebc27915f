# Probe for docs/surrogate_diagnosis.md (issue 6); a research script, not part of amfe. Run from the repository root with .venv/bin/python.
import numpy as np, h5py, sys
from amfe.model.scales import bed_for, get_scale
from amfe.model.bonds import find_bonds, bond_springs
sc=get_scale('small')
path,part,nparts=sys.argv[1],int(sys.argv[2]),int(sys.argv[3])
f=h5py.File(path); seeds=f['seed'][:]; st=f['status'][:]
n=len(seeds); out=np.zeros((n,3,3,20,20),np.float32)
for k in range(part,n,nparts):
    if st[k]!=0: continue
    bed=bed_for('small',int(seeds[k])); mat=bed.material()
    b=find_bonds(bed.centers,bed.radii)
    kn,kt,kan,kat,_=bond_springs(b,mat)
    rm=bed.radii.mean()
    p=bed.centers[b.i]+b.normal*b.d_i[:,None]
    ix=np.clip((p[:,0]/sc.cell[0]).astype(int),0,19); iy=np.clip((p[:,1]/sc.cell[1]).astype(int),0,19); iz=np.clip((p[:,2]/sc.layer_thickness).astype(int),0,2)
    flat=(iz*20+iy)*20+ix
    for c,w in enumerate([kn/(mat.E*rm), np.ones_like(kn), b.a_star]):
        out[k,c]=np.bincount(flat,w,minlength=1200).reshape(3,20,20)
np.save(f'/tmp/amfe_probe_feat_{path.split("/")[-1]}_{part}.npy',out)
