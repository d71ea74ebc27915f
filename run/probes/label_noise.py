# Probe for docs/surrogate_diagnosis.md (issue 6); a research script, not part of amfe. Run from the repository root with .venv/bin/python.
import numpy as np, sys, dataclasses
from amfe.model.scales import sample_bed_params, get_scale
from amfe.model.bed import generate_bed
from amfe.dataset.images import pixelate
from amfe.solvers.driver import homogenize_bed
from amfe.model.options import SolveOptions
from petsc4py import PETSc
sc=get_scale('small')
part=int(sys.argv[1]); out=[]
base_seeds=[s for s in range(1000,1100) if sample_bed_params('small',s)['scan'].skip_fraction==0][:12]
for bs in base_seeds[part::2]:
    p=sample_bed_params('small',bs); L=[];D=[]
    for k in range(6):
        q=dict(p); q['seed']=bs*100+k
        bed=generate_bed(**q)
        r=homogenize_bed(bed,SolveOptions(solver="gamg",material=bed.material()),PETSc.COMM_SELF).to_dict()
        pr=r['properties']; L.append([pr[n] for n in ['Ex','Ey','Ez','nu_yz','nu_xz','nu_xy']])
        img=pixelate(bed,sc.cell,sc.layer_thickness,box=[np.zeros(3),np.array(sc.size)],spacing=sc.image_spacing)
        D.append(img)
    L=np.array(L); D=np.array(D)
    cv=L.std(0,ddof=1)/np.abs(L.mean(0))*100
    print(bs, 'hi %.3f w %.3f c %.2f'%(p['enlargement'][1],p['scan'].track_width*1e3,p['scan'].track_width/p['scan'].hatch_spacing),
          'CV%', np.round(cv,2), 'img pix std', round(float(D.std(0).mean()),4), 'dens', round(float(D.mean()),3), flush=True)
