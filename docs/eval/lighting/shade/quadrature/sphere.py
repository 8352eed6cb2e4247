import numpy as np
exec(open('docs/eval/lighting/shade/quadrature/cylinder.py').read().split("V=np.array")[0])
V=np.array([0,0,1.0])
low=np.radians(15)
suns={'back':norm(np.array([0,np.sin(low),-np.cos(low)])),'side':norm(np.array([np.cos(low),np.sin(low),0])),'front':norm(np.array([4,8,6.0])),
      'back_side':norm(np.array([0.7,0.3,-0.6])),'high_behind':norm(np.array([0,0.9,-0.4]))}
def frame(L):
    p=L-V*np.dot(L,V); 
    if np.linalg.norm(p)<1e-9: p=np.array([1.0,0,0])
    side=norm(p); up=np.cross(V,side); return side,up
def dense(L,n=400):
    side,up=frame(L); tot=0; cnt=0
    g=(np.arange(n)+0.5)/n*2-1
    for x in g:
        for y in g:
            if x*x+y*y>=1: continue
            z=np.sqrt(1-x*x-y*y); nn=x*side+y*up+z*V
            a,b=brdf(nn,V,L); tot+=a+b; cnt+=1
    return tot/cnt
def stroud(L):
    side,up=frame(L); tot=0
    pts=[(0,0,0.25)]+[(0.81649658*np.cos(k*np.pi/3),0.81649658*np.sin(k*np.pi/3),0.125) for k in range(6)]
    for x,y,w in pts:
        z=np.sqrt(max(1-x*x-y*y,0)); nn=x*side+y*up+z*V; a,b=brdf(nn,V,L); tot+=w*(a+b)
    return tot
def litrule(L,nt=3,nu=2):
    side,up=frame(L); lz=np.dot(L,V)
    xt,wt=np.polynomial.legendre.leggauss(nt); xu,wu=np.polynomial.legendre.leggauss(nu)
    tot=0
    for ti,wti in zip(xt*np.pi/2,wt*np.pi/2):
        w=np.cos(ti); y=np.sin(ti)
        for ui,wui in zip(xu,wu):
            x=w*(-lz+(1+lz)*(ui+1)/2)
            z=np.sqrt(max(1-x*x-y*y,0)); nn=x*side+y*up+z*V; a,b=brdf(nn,V,L)
            tot+=(1+lz)/2*w*w*wti*wui*(a+b)
    return tot/np.pi
for name,L in suns.items():
    d=dense(L); print(name, round(d,5), 'stroud', round(stroud(L)/d,3), 'lit3x2', round(litrule(L)/d,3), 'lit2x3', round(litrule(L,2,3)/d,3),'lit3x3',round(litrule(L,3,3)/d,3),'lit4x2',round(litrule(L,4,2)/d,3))
print('lambert check')
def brdf(n,V,L,**k):
    return max(np.dot(n,L),0),0.0
for name,L in suns.items():
    al=np.arccos(np.clip(np.dot(V,L),-1,1)); ex=2*(np.sin(al)+(np.pi-al)*np.cos(al))/(3*np.pi)
    print(name, round(ex,4), round(dense(L,200),4), round(litrule(L),4), round(litrule(L,4,4),4))
