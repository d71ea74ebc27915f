# Probe for docs/surrogate_diagnosis.md (issue 6); a research script, not part of amfe. Run from the repository root with .venv/bin/python.
import h5py, numpy as np, torch, sys
torch.set_num_threads(2)
def load(p):
    f=h5py.File(p); ok=f['status'][:]==0
    P=f['params']; 
    ang=np.deg2rad(P['angle'][:])
    feats=np.stack([P['enlargement_hi'][:],P['coverage'][:],P['track_width'][:]*1e3,np.cos(2*ang),np.sin(2*ang),
        P['layer_rotation'][:]/90,P['offset'][:]/P['hatch_spacing'][:],P['skip_fraction'][:],P['skip_length'][:]*1e3,f['density'][:]],1)
    img=f['images'][:].reshape(len(ok),-1)
    return feats[ok],img[ok],f['labels'][:][ok]
which=sys.argv[1]
Xa,Ia,Ya=load('/work/data/small_train.h5'); Xb,Ib,Yb=load('/work/data/small_test.h5')
if which=='params': pass
elif which=='noenl': Xa=Xa[:,1:]; Xb=Xb[:,1:]
elif which=='density': Xa=Xa[:,[-1]]; Xb=Xb[:,[-1]]
elif which=='dens_enl': Xa=Xa[:,[0,-1]]; Xb=Xb[:,[0,-1]]
def tf(Y): Y=Y.copy(); Y[:,:3]=np.log(Y[:,:3]); return Y
Ta,Tb=tf(Ya),tf(Yb); mu,sd=Ta.mean(0),Ta.std(0); xm,xs=Xa.mean(0),Xa.std(0)+1e-12
xa=torch.tensor((Xa-xm)/xs,dtype=torch.float32); ya=torch.tensor((Ta-mu)/sd,dtype=torch.float32)
xb=torch.tensor((Xb-xm)/xs,dtype=torch.float32)
torch.manual_seed(0)
net=torch.nn.Sequential(torch.nn.Linear(xa.shape[1],128),torch.nn.SiLU(),torch.nn.Linear(128,128),torch.nn.SiLU(),torch.nn.Linear(128,6))
opt=torch.optim.Adam(net.parameters(),1e-3,weight_decay=1e-5)
E=3000; sch=torch.optim.lr_scheduler.CosineAnnealingLR(opt,E)
for e in range(E):
    perm=torch.randperm(len(xa))
    for i in range(0,len(xa),100):
        b=perm[i:i+100]; opt.zero_grad(); l=((net(xa[b])-ya[b])**2).mean(); l.backward(); opt.step()
    sch.step()
with torch.no_grad(): pb=net(xb).numpy()*sd+mu
pb[:,:3]=np.exp(pb[:,:3])
err=np.abs(pb-Yb)/np.abs(Yb)*100
print(which, 'mean rel err %', np.round(err.mean(0),2))
