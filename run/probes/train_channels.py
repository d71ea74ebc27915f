# Probe for docs/surrogate_diagnosis.md (issue 6); a research script, not part of amfe. Run from the repository root with .venv/bin/python.
import numpy as np, h5py, torch, sys, time
from amfe.training.nets import build_net
from amfe.training.data import Normalizer, augment_batch, split_indices
torch.set_num_threads(1)
variant=sys.argv[1]; E=int(sys.argv[2]) if len(sys.argv)>2 else 300
def load(name):
    f=h5py.File(f'/work/data/{name}'); ok=f['status'][:]==0
    F=np.load(f'/tmp/amfe_probe_feat_{name}_0.npy')+np.load(f'/tmp/amfe_probe_feat_{name}_1.npy')
    img=f['images'][:]
    hi=f['params']['enlargement_hi'][:]
    ch=[img]
    if 'kn' in variant: ch.append(F[:,0]/50.0)
    if 'cnt' in variant: ch.append(F[:,1]/50.0)
    if 'as' in variant: ch.append(F[:,2]/F[:,1].clip(1))
    if 'hi' in variant: ch.append(np.broadcast_to(((hi-1.1)/0.04)[:,None,None,None],(len(hi),1,20,20)))
    X=np.concatenate(ch,1).astype(np.float32)
    return X[ok],f['labels'][:][ok]
Xa,Ya=load('small_train.h5'); Xt,Yt=load('small_test.h5')
tr,va=split_indices(np.arange(len(Xa)),0.2,0)
norm=Normalizer.fit(Ya[tr])
torch.manual_seed(0); g=torch.Generator().manual_seed(0)
net=build_net('custom',Xa.shape[1:])
opt=torch.optim.Adam(net.parameters(),1e-3); sch=torch.optim.lr_scheduler.CosineAnnealingLR(opt,E)
X=torch.tensor(Xa[tr]); Y=torch.tensor(Ya[tr])
t0=time.time()
for e in range(E):
    net.train(); perm=torch.randperm(len(X),generator=g)
    for i in range(0,len(X),100):
        b=perm[i:i+100]; x,y=augment_batch(X[b],Y[b],'d4',g)
        if 'zf' in variant:
            B=x.shape[0]; x5=x.view(B,-1,3,20,20); fz=(torch.rand(B,generator=g)<0.5).view(B,1,1,1,1)
            x=torch.where(fz,x5.flip(2),x5).reshape(B,-1,20,20)
        opt.zero_grad(); l=((net(x)-norm.encode(y))**2).mean(); l.backward(); opt.step()
    sch.step()
net.eval()
def ev(Xe,Ye):
    with torch.no_grad(): p=norm.decode(net(torch.tensor(Xe))).numpy()
    return np.abs(p-Ye)/np.abs(Ye)*100
ptr=ev(Xa[tr][:400],Ya[tr][:400]).mean(0)
print(variant,E,'train',np.round(ptr,2),'%.0fs'%(time.time()-t0),'val',np.round(ev(Xa[va],Ya[va]).mean(0),2),'test',np.round(ev(Xt,Yt).mean(0),2),flush=True)
