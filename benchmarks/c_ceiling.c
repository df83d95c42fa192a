/* A ceiling estimate, not part of dgtd: Algorithm 1's agent step for dense features, in C with AVX2 intrinsics,
 * structured as dgtd's compiled kernel (one pass per agent: neighbour sums in registers, v, mu, w, theta and the
 * running sum of w, projections; in case B the next agent's dot products inside the pass, or with "0" as second
 * argument before each pass), to see what this machine gives that structure when a C compiler writes it. It draws states from
 * alias tables as large as case B's (NO_ALIAS=1: uniform states), but it is not dgtd's arithmetic bit for bit
 * and keeps no checkpoints. Cases as in benchmarks/throughput.py: B (16 agents, 32 seeds, seeds over the
 * threads), C (1000 agents on a banded graph of mean degree 10) and D (10 000 agents, ring plus random chords,
 * mean degree 6), agents over the threads; q = 64 throughout.
 *
 *   gcc -O3 -mavx2 -mfma -ffp-contract=off -fopenmp benchmarks/c_ceiling.c -o /tmp/c_ceiling -lm
 *   OMP_NUM_THREADS=2 /tmp/c_ceiling B        # prints the best of 3 runs, agent-steps per second
 */
#include <immintrin.h>
#include <stdio.h>
#include <stdlib.h>
#include <stdint.h>
#include <string.h>
#include <time.h>
#include <omp.h>
typedef struct { uint64_t hi, lo, ihi, ilo; } pcg;
static inline double pcg_next(pcg *g){
  const uint64_t MH=2549297995355413924ULL, ML=4865540595714422341ULL;
  unsigned __int128 st=((unsigned __int128)g->hi<<64)|g->lo, inc=((unsigned __int128)g->ihi<<64)|g->ilo;
  st = st*(((unsigned __int128)MH<<64)|ML) + inc; g->hi=st>>64; g->lo=(uint64_t)st;
  uint64_t x=g->hi^g->lo; unsigned rot=g->hi>>58; uint64_t out=(x>>rot)|(x<<((-rot)&63));
  return (out>>11)*(1.0/9007199254740992.0);
}
#define Q 64
typedef struct { int N,S,E; int *indptr,*nbr,*eid; double *Phi,*p; double *dprob; long *dalias; double *sprob; long *salias; } Graph;
static int ALIAS=0;
typedef struct { double *R; double *Z[2]; int cur; pcg g; int *s,*sn; double *r; char *up; } Seed;
// record per agent: theta, v, mu, sa  (4Q)
static inline __m256d clip(__m256d x, __m256d b, __m256d nb){ return _mm256_max_pd(_mm256_min_pd(x,b),nb); }
static inline double hsum(__m256d v){ __m128d lo=_mm256_castpd256_pd128(v), hi=_mm256_extractf128_pd(v,1);
  double e0=_mm_cvtsd_f64(lo), e1=_mm_cvtsd_f64(_mm_unpackhi_pd(lo,lo)), e2=_mm_cvtsd_f64(hi), e3=_mm_cvtsd_f64(_mm_unpackhi_pd(hi,hi)); return (e0+e1)+(e2+e3); }
static int TAILSEP=0;
#define BODY(CNT) \
  for(int f=0; f<Q; f+=4){ \
    __m256d w=_mm256_load_pd(zi+f), z=_mm256_load_pd(zi+Q+f); \
    __m256d lw=_mm256_mul_pd(C,w), lz=_mm256_mul_pd(C,z); \
    for(int k=0;k<CNT;k++){ lw=_mm256_sub_pd(lw,_mm256_load_pd(js[k]+f)); lz=_mm256_sub_pd(lz,_mm256_load_pd(js[k]+Q+f)); } \
    _mm256_store_pd(sa+f,_mm256_add_pd(_mm256_load_pd(sa+f),w)); \
    __m256d vf=_mm256_load_pd(v+f), muf=_mm256_load_pd(mu+f); \
    __m256d vn=clip(_mm256_sub_pd(vf,_mm256_mul_pd(A,_mm256_sub_pd(vf,lw))),bv,nbv); \
    __m256d mun=clip(_mm256_sub_pd(muf,_mm256_mul_pd(A,_mm256_add_pd(_mm256_sub_pd(_mm256_setzero_pd(),lw),_mm256_mul_pd(RHO,muf)))),bmu,nbmu); \
    _mm256_store_pd(v+f,vn); _mm256_store_pd(mu+f,mun); _mm256_store_pd(zo+Q+f,_mm256_add_pd(vn,mun)); \
    __m256d phs=_mm256_load_pd(ps+f); \
    __m256d gw=_mm256_sub_pd(_mm256_sub_pd(_mm256_sub_pd(_mm256_mul_pd(RT,_mm256_sub_pd(phs,_mm256_mul_pd(GA,_mm256_load_pd(psn+f)))),lz),_mm256_mul_pd(K,lw)),_mm256_mul_pd(RHO,w)); \
    _mm256_store_pd(zo+f,clip(_mm256_add_pd(w,_mm256_mul_pd(A,gw)),bw,nbw)); \
    _mm256_store_pd(th+f,clip(_mm256_sub_pd(_mm256_load_pd(th+f),_mm256_mul_pd(A,_mm256_mul_pd(phs,CT))),bth,nbth)); \
    if(has_next){ __m256d a=_mm256_load_pd(nps+f), b=_mm256_load_pd(npsn+f), wn=_mm256_load_pd(nw+f); \
      d0=_mm256_add_pd(d0,_mm256_mul_pd(a,_mm256_load_pd(nth+f))); d1=_mm256_add_pd(d1,_mm256_mul_pd(a,wn)); d2=_mm256_add_pd(d2,_mm256_mul_pd(b,wn)); } \
  }

static inline void agent_pass(const Graph *restrict G, Seed *restrict sd, int i, double alpha, double rt, double ct,
   double gamma, double kappa, double rho, const double *bx, int nx, double *dn)
{
  const double *restrict Zi=sd->Z[sd->cur]; const double *restrict zi=Zi+(size_t)i*2*Q; double *restrict zo=sd->Z[sd->cur^1]+(size_t)i*2*Q;
  double *restrict rec=sd->R+(size_t)i*4*Q; double *restrict th=rec, *restrict v=rec+Q, *restrict mu=rec+2*Q, *restrict sa=rec+3*Q;
  const double *restrict ps=G->Phi+(size_t)sd->s[i]*Q, *restrict psn=G->Phi+(size_t)sd->sn[i]*Q;
  const double *js[32]; int cnt=0;
  for(int p=G->indptr[i]; p<G->indptr[i+1]; p++){ js[cnt]=Zi+(size_t)G->nbr[p]*2*Q; cnt+=sd->up[G->eid[p]]; }
  __m256d A=_mm256_set1_pd(alpha), RHO=_mm256_set1_pd(rho), K=_mm256_set1_pd(kappa), GA=_mm256_set1_pd(gamma),
          RT=_mm256_set1_pd(rt), CT=_mm256_set1_pd(ct), C=_mm256_set1_pd((double)cnt);
  __m256d bth=_mm256_set1_pd(bx[0]), nbth=_mm256_set1_pd(-bx[0]), bv=_mm256_set1_pd(bx[1]), nbv=_mm256_set1_pd(-bx[1]),
          bmu=_mm256_set1_pd(bx[2]), nbmu=_mm256_set1_pd(-bx[2]), bw=_mm256_set1_pd(bx[3]), nbw=_mm256_set1_pd(-bx[3]);
  const int has_next = nx>=0;
  const double *nps=G->Phi, *npsn=G->Phi, *nth=th, *nw=zi;
  if(has_next){ nps=G->Phi+(size_t)sd->s[nx]*Q; npsn=G->Phi+(size_t)sd->sn[nx]*Q; nth=sd->R+(size_t)nx*4*Q; nw=Zi+(size_t)nx*2*Q; }
  __m256d d0=_mm256_setzero_pd(), d1=d0, d2=d0;
  switch(cnt){ case 0: BODY(0) break; case 1: BODY(1) break; case 2: BODY(2) break; case 3: BODY(3) break; case 4: BODY(4) break;
    case 5: BODY(5) break; case 6: BODY(6) break; default: BODY(cnt) break; }
  if(has_next){ dn[0]=hsum(d0); dn[1]=hsum(d1); dn[2]=hsum(d2); }
}
static void dots(const Graph *G, Seed *sd, int i, double *d){
  const double *ps=G->Phi+(size_t)sd->s[i]*Q, *psn=G->Phi+(size_t)sd->sn[i]*Q, *th=sd->R+(size_t)i*4*Q, *w=sd->Z[sd->cur]+(size_t)i*2*Q;
  __m256d d0=_mm256_setzero_pd(), d1=d0, d2=d0;
  for(int f=0;f<Q;f+=4){ __m256d a=_mm256_load_pd(ps+f), b=_mm256_load_pd(psn+f), wn=_mm256_load_pd(w+f);
    d0=_mm256_add_pd(d0,_mm256_mul_pd(a,_mm256_load_pd(th+f))); d1=_mm256_add_pd(d1,_mm256_mul_pd(a,wn)); d2=_mm256_add_pd(d2,_mm256_mul_pd(b,wn)); }
  d[0]=hsum(d0); d[1]=hsum(d1); d[2]=hsum(d2);
}
static void sample(const Graph *G, Seed *sd){
  if(ALIAS){ int K=G->S; for(int i=0;i<G->N;i++){ double u=pcg_next(&sd->g); double x=u*K; long j=(long)x; if(j>K-1) j=K-1; long s0 = (x-j<G->dprob[j])? j : G->dalias[j];
     double u2=pcg_next(&sd->g); double x2=u2*K; long j2=(long)x2; if(j2>K-1) j2=K-1; long o = (x2-j2<G->sprob[s0*K+j2])? j2 : G->salias[s0*K+j2];
     sd->s[i]=(int)s0; sd->sn[i]=(int)(o%G->S); sd->r[i]=u2; } }
  else for(int i=0;i<G->N;i++){ double u=pcg_next(&sd->g); sd->s[i]=(int)(u*G->S); double u2=pcg_next(&sd->g); sd->sn[i]=(int)(u2*G->S); sd->r[i]=u2; }
  for(int e=0;e<G->E;e++){ sd->up[e]= pcg_next(&sd->g) < G->p[e]; }
}
static void seed_step(const Graph *G, Seed *sd, double alpha, int pipelined){
  const double bx[4]={100,100,100,100}; double gamma=0.9,kappa=1,rho=0;
  sample(G,sd);
  double d[3]; if(pipelined) dots(G,sd,0,d);
  for(int i=0;i<G->N;i++){
    if(!pipelined) dots(G,sd,i,d);
    double r=sd->r[i], ct=d[0]+(d[1]-gamma*d[2]-r), rt=d[0]; double dn[3];
    agent_pass(G,sd,i,alpha,rt,ct,gamma,kappa,rho,bx, pipelined && i+1<G->N ? i+1 : -1, dn);
    if(pipelined){ d[0]=dn[0]; d[1]=dn[1]; d[2]=dn[2]; }
  }
  sd->cur^=1;
}
static Seed make_seed(const Graph *G, int b){
  Seed s; int N=G->N; size_t PAD=getenv("PAD")?atoi(getenv("PAD")):0;
  s.R=aligned_alloc(64,sizeof(double)*N*4*Q); memset(s.R,0,sizeof(double)*N*4*Q);
  double *z=aligned_alloc(64,sizeof(double)*(N*4*Q+PAD)); memset(z,0,sizeof(double)*(N*4*Q+PAD)); s.Z[0]=z; s.Z[1]=z+N*2*Q+PAD; s.cur=0;
  s.g.hi=0x12345+b; s.g.lo=0x9876543+b*7; s.g.ihi=0x1; s.g.ilo=(2*b+1)|1;
  s.s=malloc(sizeof(int)*N); s.sn=malloc(sizeof(int)*N); s.r=malloc(sizeof(double)*N); s.up=malloc(G->E); return s;
}
static void csr(Graph *G, int N, int E, int (*ed)[2]){
  G->N=N; G->E=E; G->indptr=calloc(N+1,sizeof(int)); G->nbr=malloc(sizeof(int)*2*E); G->eid=malloc(sizeof(int)*2*E);
  for(int e=0;e<E;e++){ G->indptr[ed[e][0]+1]++; G->indptr[ed[e][1]+1]++; } for(int i=0;i<N;i++) G->indptr[i+1]+=G->indptr[i];
  int *pos=malloc(sizeof(int)*N); memcpy(pos,G->indptr,sizeof(int)*N);
  for(int e=0;e<E;e++){ int a=ed[e][0],b=ed[e][1]; G->nbr[pos[a]]=b; G->eid[pos[a]++]=e; G->nbr[pos[b]]=a; G->eid[pos[b]++]=e; }
}
static double now(){ struct timespec t; clock_gettime(CLOCK_MONOTONIC,&t); return t.tv_sec+1e-9*t.tv_nsec; }
int main(int argc, char **argv){
  int cas=argv[1][0]; int pipelined=argc>2?atoi(argv[2]):1;
  Graph G; G.S=128; int N,E,B,T; int (*ed)[2]; srand(1);
  if(cas=='B'){ N=getenv("NN")?atoi(getenv("NN")):16; B=32; T=20000*16/N; E=2*N; if(getenv("SS")) G.S=atoi(getenv("SS")); ed=malloc(sizeof(int)*2*E); for(int i=0;i<N;i++){ ed[i][0]=i; ed[i][1]=(i+1)%N; ed[N+i][0]=i; ed[N+i][1]=(i+4)%N; } }
  else if(cas=='C'){ N=1000; B=1; T=3000; E=5000; ed=malloc(sizeof(int)*2*E); for(int e=0;e<E;e++){ int i=e/5, k=e%5; ed[e][0]=i; ed[e][1]=(i+1+k*(1+rand()%6))%N; } }
  else { N=10000; B=1; T=300; E=30000; ed=malloc(sizeof(int)*2*E); for(int e=0;e<E;e++){ ed[e][0]=e%N; ed[e][1]= e<N ? (e+1)%N : rand()%N; if(ed[e][1]==ed[e][0]) ed[e][1]=(ed[e][0]+1)%N; } }
  csr(&G,N,E,ed);
  G.Phi=aligned_alloc(64,sizeof(double)*G.S*Q); for(int k=0;k<G.S*Q;k++) G.Phi[k]=rand()/(double)RAND_MAX;
  ALIAS=!getenv("NO_ALIAS"); G.dprob=malloc(8*G.S); G.dalias=malloc(8*G.S); G.sprob=malloc(8*G.S*G.S); G.salias=malloc(8*G.S*G.S);
  for(int k=0;k<G.S;k++){ G.dprob[k]=rand()/(double)RAND_MAX; G.dalias[k]=rand()%G.S; } for(long k=0;k<(long)G.S*G.S;k++){ G.sprob[k]=rand()/(double)RAND_MAX; G.salias[k]=rand()%G.S; }
  G.p=malloc(sizeof(double)*E); for(int e=0;e<E;e++) G.p[e]= cas=='B'?0.5:0.9;
  Seed *sd=malloc(sizeof(Seed)*B); for(int b=0;b<B;b++) sd[b]=make_seed(&G,b);
  double best=0;
  for(int rep=0;rep<3;rep++){
  double t0=now();
  if(B>1){
    #pragma omp parallel for schedule(static)
    for(int b=0;b<B;b++) for(int t=0;t<T;t++) seed_step(&G,&sd[b],0.5/__builtin_sqrt(t+10.0),pipelined);
  } else {
    Seed *s0=&sd[0];
    #pragma omp parallel
    { for(int t=0;t<T;t++){
        #pragma omp single
        sample(&G,s0);
        const double bx[4]={100,100,100,100}; double alpha=0.5/__builtin_sqrt(t+10.0);
        #pragma omp for schedule(static)
        for(int i=0;i<N;i++){ double d[3],dn[3]; dots(&G,s0,i,d); agent_pass(&G,s0,i,alpha,d[0],d[0]+(d[1]-0.9*d[2]-s0->r[i]),0.9,1,0,bx,-1,dn); }
        #pragma omp single
        s0->cur^=1; } }
  }
  double r=(double)T*B*N/(now()-t0)/1e6; if(r>best) best=r; }
  printf("%c pipelined=%d: best %.2f M agent-steps/s (%d threads)\n",cas,pipelined,best,omp_get_max_threads());
  return 0;
}
