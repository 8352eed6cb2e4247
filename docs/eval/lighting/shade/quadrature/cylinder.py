import numpy as np
def norm(v): return v/np.linalg.norm(v)
def brdf(n,V,L,rough_p=0.6,albedo=0.05,F0=0.04):
    a=rough_p**2
    NdotV=max(np.dot(n,V),1e-4); NdotL=np.dot(n,L)
    if NdotL<=0: return 0.0,0.0
    H=norm(V+L); NdotH=max(np.dot(n,H),0); LdotH=max(np.dot(L,H),0)
    # GGX D
    k=a*a; d=(NdotH*NdotH*(k-1)+1); D=k/(np.pi*d*d)
    # Smith correlated visibility
    lv=NdotL*np.sqrt(NdotV*NdotV*(1-k)+k); ll=NdotV*np.sqrt(NdotL*NdotL*(1-k)+k); Vis=0.5/(lv+ll)
    F=F0+(1-F0)*(1-LdotH)**5
    spec=D*Vis*F
    # Burley
    f90=0.5+2*a*LdotH*LdotH
    fd=(1+(f90-1)*(1-NdotL)**5)*(1+(f90-1)*(1-NdotV)**5)/np.pi
    return albedo*fd*NdotL, spec*NdotL
V=np.array([0,0,1.0])
low=np.radians(15)
suns={'back':norm(np.array([0,np.sin(low),-np.cos(low)])),'side':norm(np.array([np.cos(low),np.sin(low),0])),'front':norm(np.array([4,8,6.0]))}
# GL nodes
xg,wg=np.polynomial.legendre.leggauss(4)
def cyl(T,L,mode,n=4000):
    T=norm(T); toward=norm(V-T*np.dot(T,V)); side=np.cross(T,toward)
    if mode=='dense':
        s=np.linspace(-1,1,n+1); s=(s[1:]+s[:-1])/2; w=np.full(n,2.0/n)
    elif mode=='gl_s':
        s=xg; w=wg
    elif mode=='gl_theta':
        th=xg*np.pi/2; s=np.sin(th); w=wg*np.pi/2*np.cos(th)
    d=sp=0
    for si,wi in zip(s,w):
        nn=np.sqrt(max(1-si*si,0))*toward+si*side
        a,b=brdf(nn,V,L); d+=wi*a/2; sp+=wi*b/2
    return d,sp
rng=np.random.default_rng(1)
for name,L in suns.items():
    acc={m:np.zeros(2) for m in ['dense','gl_s','gl_theta']}
    for i in range(300):
        T=rng.normal(size=3)
        for m in acc: acc[m]+=np.array(cyl(T,L,m))
    print(name, {m:(v/300).round(5) for m,v in acc.items()})
print('---')
def cyl2(T,L,var,n):
    T=norm(T); toward=norm(V-T*np.dot(T,V)); side=np.cross(T,toward)
    x,w=np.polynomial.legendre.leggauss(n)
    if var=='s': s=x
    else:
        th=x*np.pi/2; s=np.sin(th); w=w*np.pi/2*np.cos(th)
    tot=0
    for si,wi in zip(s,w):
        nn=np.sqrt(max(1-si*si,0))*toward+si*side
        a,b=brdf(nn,V,L); tot+=wi*(a+b)/2
    return tot
Ts=[rng.normal(size=3) for i in range(200)]
for name,L in suns.items():
    dense=np.mean([sum(cyl(T,L,'dense')) for T in Ts])
    out=[]
    for var in ['s','th']:
        for n in [4,5,6,8]:
            v=np.mean([cyl2(T,L,var,n) for T in Ts]); out.append(f"{var}{n}:{v/dense:.3f}")
    print(name, round(dense,5), ' '.join(out))
print('--- lit interval')
def cyl3(T,L,n):
    T=norm(T); toward=norm(V-T*np.dot(T,V)); side=np.cross(T,toward)
    a=np.dot(toward,L); b=np.dot(side,L)
    phi=np.arctan2(b,a)
    t0=max(-np.pi/2,phi-np.pi/2); t1=min(np.pi/2,phi+np.pi/2)
    if t1<=t0: return 0.0
    x,w=np.polynomial.legendre.leggauss(n)
    th=(t0+t1)/2+x*(t1-t0)/2; w=w*(t1-t0)/2*np.cos(th)
    tot=0
    for t,wi in zip(th,w):
        nn=np.cos(t)*toward+np.sin(t)*side
        a_,b_=brdf(nn,V,L); tot+=wi*(a_+b_)/2
    return tot
for name,L in suns.items():
    dense=np.mean([sum(cyl(T,L,'dense')) for T in Ts])
    out=[]
    for n in [3,4,5,6]:
        v=np.mean([cyl3(T,L,n) for T in Ts]); out.append(f"lit{n}:{v/dense:.3f}")
    # per-orientation relative error spread for n=4
    errs=[abs(cyl3(T,L,4)-sum(cyl(T,L,'dense')))/max(sum(cyl(T,L,'dense')),1e-9) for T in Ts[:60]]
    print(name, ' '.join(out), 'median rel err n4', round(float(np.median(errs)),3))
print('--- variants')
def cylS(T,L,n):
    T=norm(T); toward=norm(V-T*np.dot(T,V)); side=np.cross(T,toward)
    a=np.dot(toward,L); b=np.dot(side,L); phi=np.arctan2(b,a)
    t0=max(-np.pi/2,phi-np.pi/2); t1=min(np.pi/2,phi+np.pi/2)
    if t1<=t0: return 0.0
    s0,s1=np.sin(t0),np.sin(t1)
    x,w=np.polynomial.legendre.leggauss(n)
    s=(s0+s1)/2+x*(s1-s0)/2; w=w*(s1-s0)/2
    tot=0
    for si,wi in zip(s,w):
        nn=np.sqrt(max(1-si*si,0))*toward+si*side
        a_,b_=brdf(nn,V,L); tot+=wi*(a_+b_)/2
    return tot
def blend(T,L):
    Tn=norm(T); toward=norm(V-Tn*np.dot(Tn,V)); a=np.dot(toward,norm(L))
    t=np.clip((0.25-a)/0.5,0,1)  # 1 when a<-0.25 (back), 0 when a>0.25
    t=t*t*(3-2*t)
    return (1-t)*cyl2(T,L,'s',4)+t*cyl3(T,L,4)
for name,L in suns.items():
    d=[sum(cyl(T,L,'dense')) for T in Ts]; dense=np.mean(d)
    vS=[cylS(T,L,4) for T in Ts]; vB=[blend(T,L) for T in Ts]
    print(name, 'litS4', round(np.mean(vS)/dense,3), 'blend', round(np.mean(vB)/dense,3),
      'medrel litS4', round(float(np.median(np.abs(np.array(vS)-d)/np.maximum(d,1e-9))),3),
      'medrel blend', round(float(np.median(np.abs(np.array(vB)-d)/np.maximum(d,1e-9))),3))
