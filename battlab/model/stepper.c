/* battlab time stepper: variable-step BDF2 with Newton, static-pivot sparse LU and exact forward
 * sensitivities (staggered direct method). Appended to CasADi-generated code that defines
 *   bl_res(y, xn, xp, u, th) -> R                 residual of one step (rows: x - psi - gamma h f; g)
 *   bl_jac(y, xn, xp, u, th) -> dR/dy, dR/dth     sparse, CCS nonzeros (a null second output is not written)
 *   bl_g(y, u, th)           -> g                 the algebraic rows alone (zero-length solves)
 *   bl_out(y, u, th)         -> [V, T1, T2, sto_min, sto_max]
 *   bl_outj(y, u, th)         -> dV/dy (dense), dV/dth (dense)
 * u = [h, omega, I_dis, T_amb]. Everything below is generic in the model.
 *
 * A zero-length solve (the consistent start, the right limit at a current change) keeps the differential states
 * and solves g(x, z) = 0 for the algebraic ones: Newton and the sensitivities S_z = -g_z^-1 (g_x S_x + g_th) work
 * on the nz algebraic unknowns only; their Jacobians are gathered from the step's (h = 0: the algebraic rows are
 * the same). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* kinds of work, counted with their cycles in a profiling build (BATTLAB_PROFILE_STEPPER=1) */
enum { PR_RES, PR_JAC, PR_JTH, PR_G, PR_OUT, PR_OUTJ, PR_FACTOR, PR_SOLVE, PR_SOLVE_MULTI, PR_N };
#ifdef BL_PROFILE
#include <x86intrin.h>
static double g_prof[2 * PR_N];
#define PROF_BEGIN unsigned long long prof_t0 = __rdtsc()
#define PROF_END(k) (g_prof[2 * (k)] += 1.0, g_prof[2 * (k) + 1] += (double)(__rdtsc() - prof_t0))
void bl_profile(double *out) { memcpy(out, g_prof, sizeof g_prof); memset(g_prof, 0, sizeof g_prof); }
#else
#define PROF_BEGIN
#define PROF_END(k)
#endif

typedef struct {
  int n, nx, nth;               /* unknowns (ny for steps, nz for zero-length solves), differential states, th */
  /* LU program on the permuted, filled pattern */
  int nslot;
  const int *prow, *pcol;       /* position -> original row / column */
  const int *jac2slot;          /* Jacobian nonzero -> slot */
  const int *piv;               /* [n] slot of the pivot of column k */
  const int *lptr, *lrow, *lslot; /* column k of L below the diagonal: rows and slots */
  const int *uptr, *uslot;      /* row k of U right of the diagonal: slots (factorisation order) */
  const int *upd;               /* update targets, nested L x U loop order */
  const int *ucptr, *ucrow, *ucslot; /* column k of U above the diagonal (back substitution) */
  /* Jacobian wrt theta (CCS): dR/dth for steps, dg/dth for zero-length solves */
  const int *jth_colptr, *jth_row;
  int jac_nnz, jth_nnz;
  int iT2;                      /* index of T2 in y */
  /* zero-length solves: dg/dx (CCS over the nx differential columns, rows in z), and where dg/dz, dg/dx and dg/dth
     sit in the step's dR/dy and dR/dth (nonzero positions) */
  const int *gx_colptr, *gx_row;
  int gx_nnz;
  const int *gz_at, *gx_at, *gth_at;
  /* steps: the kind of each nonzero of dR/dy (0: an algebraic row, 1: a differential row off the diagonal, 2: on
     it), to scale the Jacobian of one step size to another */
  const int *jac_kind;
} Problem;

/* CasADi work vectors, sized for the largest function (arg/res may be used beyond the inputs/outputs); one set
   per thread, so that bl_run is reentrant (the fit runs experiments on several threads) */
static _Thread_local const casadi_real *g_arg[256];
static _Thread_local casadi_real *g_res[256];
static _Thread_local casadi_int *g_iw = 0;
static _Thread_local double *g_w = 0;

typedef int (*casadi_fn)(const casadi_real **, casadi_real **, casadi_int *, casadi_real *, int);

static int ensure_work(void) {
  casadi_int a, r, i, w, ma = 0, mr = 0, mi = 0, mw = 0;
  int (*works[5])(casadi_int *, casadi_int *, casadi_int *, casadi_int *) = {bl_res_work, bl_jac_work, bl_g_work,
                                                                              bl_out_work, bl_outj_work};
  if (g_w) return 0;
  for (int k = 0; k < 5; ++k) {
    works[k](&a, &r, &i, &w);
    if (a > ma) ma = a;
    if (r > mr) mr = r;
    if (i > mi) mi = i;
    if (w > mw) mw = w;
  }
  if (ma > 256 || mr > 256) return -1;
  g_iw = (casadi_int *)malloc(sizeof(casadi_int) * (size_t)(mi + 1));
  g_w = (double *)malloc(sizeof(double) * (size_t)(mw + 1));
  return g_w && g_iw ? 0 : -1;
}

static void call(casadi_fn f, int kind, const double *a0, const double *a1, const double *a2, const double *a3,
                 const double *a4, double *r0, double *r1, double *r2) {
  g_arg[0] = a0; g_arg[1] = a1; g_arg[2] = a2; g_arg[3] = a3; g_arg[4] = a4;
  g_res[0] = r0; g_res[1] = r1; g_res[2] = r2;
  PROF_BEGIN;
  f(g_arg, g_res, g_iw, g_w, 0);
  PROF_END(kind);
  (void)kind;
}

/* numeric LU on the fixed program; returns 0 or -1 on a tiny pivot. Each pivot's slot then holds its reciprocal
   (the solves multiply: a division on their dependency chain costs about ten multiplications) */
static int lu_factor(const Problem *P, const double *jnz, double *a) {
  int k, l, u, o = 0;
  double anorm = 0.0;
  PROF_BEGIN;
  memset(a, 0, sizeof(double) * P->nslot);
  for (k = 0; k < P->jac_nnz; ++k) {
    a[P->jac2slot[k]] = jnz[k];
    if (fabs(jnz[k]) > anorm) anorm = fabs(jnz[k]);
  }
  for (k = 0; k < P->n; ++k) {
    double p = a[P->piv[k]];
    /* a pivot that (nearly) vanished: the stored pivot order no longer suits this matrix */
    if (!(fabs(p) > 1e-14 * anorm) || !isfinite(p)) return -1;
    p = 1.0 / p;
    a[P->piv[k]] = p;
    for (l = P->lptr[k]; l < P->lptr[k + 1]; ++l) a[P->lslot[l]] *= p;
    for (l = P->lptr[k]; l < P->lptr[k + 1]; ++l) {
      double lik = a[P->lslot[l]];
      for (u = P->uptr[k]; u < P->uptr[k + 1]; ++u) a[P->upd[o++]] -= lik * a[P->uslot[u]];
    }
  }
  PROF_END(PR_FACTOR);
  return 0;
}

/* solve J x = b in place (b in original row order, x in original column order); c: work [n] */
static void lu_solve(const Problem *P, const double *a, double *b, double *c) {
  int k, l, n = P->n;
  PROF_BEGIN;
  for (k = 0; k < n; ++k) c[k] = b[P->prow[k]];
  for (k = 0; k < n; ++k) {
    double ck = c[k];
    if (ck != 0.0)
      for (l = P->lptr[k]; l < P->lptr[k + 1]; ++l) c[P->lrow[l]] -= a[P->lslot[l]] * ck;
  }
  for (k = n - 1; k >= 0; --k) {
    double ck = c[k] * a[P->piv[k]];
    c[k] = ck;
    if (ck != 0.0)
      for (l = P->ucptr[k]; l < P->ucptr[k + 1]; ++l) c[P->ucrow[l]] -= a[P->ucslot[l]] * ck;
  }
  for (k = 0; k < n; ++k) b[P->pcol[k]] = c[k];
  PROF_END(PR_SOLVE);
}

/* solve J X = B for ns right-hand sides at once; B is n x ns row-major (B[i*ns + j]); C: work [n*ns] */
static void lu_solve_multi(const Problem *P, const double *a, double *B, double *C, int ns) {
  int k, l, j, n = P->n;
  PROF_BEGIN;
  for (k = 0; k < n; ++k) memcpy(C + (size_t)k * ns, B + (size_t)P->prow[k] * ns, sizeof(double) * ns);
  for (k = 0; k < n; ++k) {
    const double *ck = C + (size_t)k * ns;
    for (l = P->lptr[k]; l < P->lptr[k + 1]; ++l) {
      double v = a[P->lslot[l]];
      double *ci = C + (size_t)P->lrow[l] * ns;
      for (j = 0; j < ns; ++j) ci[j] -= v * ck[j];
    }
  }
  for (k = n - 1; k >= 0; --k) {
    double *ck = C + (size_t)k * ns;
    double inv = a[P->piv[k]];
    for (j = 0; j < ns; ++j) ck[j] *= inv;
    for (l = P->ucptr[k]; l < P->ucptr[k + 1]; ++l) {
      double v = a[P->ucslot[l]];
      double *ci = C + (size_t)P->ucrow[l] * ns;
      for (j = 0; j < ns; ++j) ci[j] -= v * ck[j];
    }
  }
  for (k = 0; k < n; ++k) memcpy(B + (size_t)P->pcol[k] * ns, C + (size_t)k * ns, sizeof(double) * ns);
  PROF_END(PR_SOLVE_MULTI);
}

static double norm_inf(const double *v, int n) {
  double m = 0.0;
  int i;
  for (i = 0; i < n; ++i) {
    double x = fabs(v[i]);
    if (!(x <= m)) m = x; /* NaN propagates */
  }
  return m;
}

/* What Newton solves: a step (the step residual in all ny unknowns) or a zero-length solve (g = 0 in the nz
   algebraic unknowns, the differential states held at xn; jfull: work for the step Jacobian dg/dz is taken from). */
typedef struct {
  const Problem *P; /* the LU program of the unknowns' Jacobian */
  int zero;
  const double *xn, *xp, *u, *th;
  double *jfull;
} System;

static void sys_res(const System *s, const double *y, double *R) {
  if (s->zero) call(bl_g, PR_G, y, s->u, s->th, 0, 0, R, 0, 0);
  else call(bl_res, PR_RES, y, s->xn, s->xp, s->u, s->th, R, 0, 0);
}

static void gather(const double *from, const int *at, int n, double *to) {
  for (int k = 0; k < n; ++k) to[k] = from[at[k]];
}

static void sys_jac(const System *s, const double *y, double *jnz) {
  if (s->zero) {
    call(bl_jac, PR_JAC, y, s->xn, s->xp, s->u, s->th, s->jfull, 0, 0);
    gather(s->jfull, s->P->gz_at, s->P->jac_nnz, jnz);
  } else {
    call(bl_jac, PR_JAC, y, s->xn, s->xp, s->u, s->th, jnz, 0, 0);
  }
}

/* The step Jacobian dR/dy at gamma h = gh into jnz, from j1, the one at gamma h = 1 at the same state: the
 * differential rows are I - gamma h f_y, the algebraic rows do not depend on h. */
static void jac_scaled(const Problem *P, const double *j1, double gh, double *jnz) {
  for (int k = 0; k < P->jac_nnz; ++k) {
    int kind = P->jac_kind[k];
    jnz[k] = kind == 0 ? j1[k] : kind == 1 ? gh * j1[k] : 1.0 + gh * (j1[k] - 1.0);
  }
}

/* Newton for one solve from the guess in y (all ny entries; a zero-length solve moves the algebraic ones only).
 * dytol: the relative size of the error left by a chord update that counts as converged (1e-11 where the solution
 * must be exact to round-off, looser under error control). lu/have_lu: the chord matrix and whether there is one.
 * first: 0 the chord matrix first, 1 a Jacobian at the guess, 2 the Jacobian at the guess already in jnz (the
 * first solve after a current change, which the chord matrix of another current and step size does not suit).
 * loose: converged once the error left is below dytol, whatever the residual (a run without sensitivities under
 * error control: no derivative of it needs the solution to round-off); else the residual must be below tol too.
 * R, Rt, c: work [n]; yt: work [ny]. Returns iterations (>= 0) or -1 (no convergence), -2 (singular). */
static int newton(const System *s, double *y, double *lu, int *have_lu, double *R, double *yt, double *Rt,
                  double *jnz, double *c, double tol, int maxit, double dytol, int first, int loose) {
  const Problem *P = s->P;
  int m = P->n, off = s->zero ? P->nx : 0, ny = off + m, zero = s->zero, i;
  int it, njac = 0, fresh_last = 0, fresh_prev = 0, stale = 0;
  double prev = INFINITY, dy = INFINITY, dyp = INFINITY, dfull = INFINITY, r;
  double *yu = y + off, *ytu = yt + off;
  sys_res(s, y, R);
  r = norm_inf(R, m);
  if (zero) memcpy(yt, y, sizeof(double) * off); /* the differential states stay */
  for (it = 0; it < maxit; ++it) {
    double scale, lam = 1.0, rt = INFINITY;
    int fresh = 0;
#ifdef BL_DEBUG
    fprintf(stderr, "newton it %d r %.3e dy %.3e dyp %.3e fresh_last %d h %g I %g have_lu %d njac %d zero %d\n", it, r,
            dy, dyp, fresh_last, s->u[0], s->u[2], *have_lu, njac, zero);
#endif
    if (!isfinite(r)) return -1;
    if (r < 1e-13) return it;
    /* converged: residual below tol and the solution itself exact to ~1e-12 (so sensitivities match finite
       differences): after a Newton update with a Jacobian taken at the previous iterate the error is
       O(dy^2); after a chord update it is about rate/(1 - rate) dy, the rate measured from the last two updates
       on the same matrix (else dy itself bounds it); or the residual sits at its round-off floor */
    scale = 1.0 + norm_inf(y, ny);
    if (r < tol || (loose && it > 0)) {
      double rate = fresh_last || !(dyp < INFINITY) ? 1.0 : dy / dyp;
      double left = rate < 0.5 ? rate / (1.0 - rate) * dy : dy;
      if (r < tol && (fresh_last ? dy < 1e-6 * scale : left < dytol * scale)) return it;
      if (r < tol && r > 0.5 * prev) return it;
      /* without the residual test: after a fresh Jacobian the error is about dy^2 relative to the solution */
      if (loose && (fresh_last ? dy * dy < dytol * scale * scale : left < dytol * scale)) return it;
    }
    /* the update no longer moves the solution: the residual is at its round-off floor */
    if (dy < 1e-13 * scale && r < 1e3 * tol) return it;
    /* or there above tol: a Newton step with a fresh Jacobian, below 1e-9 relative, no longer halves the
       residual. Rows with large terms leave a floor above tol: the solid current of a well-conducting electrode,
       sigma/dx * phi_s ~ 1e7 A/m^2 per volt at 4 V, rounds to ~1e-9 in units of 1C (sigma+ = 500 S/m) */
    if (fresh_prev && dfull < 1e-9 * scale && r > 0.5 * prev && r < 1e3 * tol) return it;
    /* chord iterations on the last factorisation while they contract fast, else a fresh Jacobian */
    /* (loose: the few chord iterations left are cheaper than a Jacobian unless the contraction is slow) */
    if (!*have_lu || stale || (it == 0 && first) || (it > 0 && r > (loose ? 0.2 : 0.03) * prev && r >= tol)) {
      if (njac >= 8) return -1;
      if (!(it == 0 && first == 2)) sys_jac(s, y, jnz);
      if (lu_factor(P, jnz, lu)) { *have_lu = 0; return -2; }
      *have_lu = 1;
      fresh = 1;
      stale = 0;
      ++njac;
    }
    lu_solve(P, lu, R, c); /* R now holds the full step */
    dfull = norm_inf(R, m);
    /* backtracking on the residual norm with a fresh Jacobian (a chord step that does not contract is
       accepted and triggers a fresh Jacobian next time) */
    for (int ls = 0; ls < 8; ++ls) {
      for (i = 0; i < m; ++i) ytu[i] = yu[i] - lam * R[i];
      sys_res(s, yt, Rt);
      rt = norm_inf(Rt, m);
      if (isfinite(rt) && (!fresh || rt < r || r < tol)) break;
      lam *= 0.5;
    }
    if (zero && r >= tol && !(rt < r)) {
      /* a zero-length solve (the start, a right limit) has no mass term to temper a bad step: a chord step that
         raises the residual is not taken (a fresh Jacobian instead), and a Newton step that cannot lower a
         residual above 1e3 tol even at 1/256 means Newton is lost (the caller continues in the current) */
      if (fresh && r > 1e3 * tol) return -1;
      if (!fresh) {
        stale = 1;
        dy = dyp = dfull = INFINITY;
        sys_res(s, y, R); /* R holds the step: the residual again at the same iterate */
        continue;
      }
    }
    if (!isfinite(rt)) return -1;
    memcpy(yu, ytu, sizeof(double) * m);
    memcpy(R, Rt, sizeof(double) * m);
    prev = r;
    r = rt;
    dyp = fresh ? INFINITY : dy;
    dy = dfull * lam;
    fresh_last = fresh && lam == 1.0;
    fresh_prev = fresh;
  }
  return -1;
}

/* Sensitivities of a converged step into Sy (n x ns, row-major, Sy[i*ns + j] = dy_i/dth_sel[j]; sel[j] < 0: a
 * direction of the start state alone, whose initial sensitivities the caller sets, with no dR/dth term):
 * J Sy = -(alpha SN + beta SP on the x rows + dR/dth[:, sel]); SN, SP: the full sensitivities of the step's start
 * and of the one before (their x rows are read). C: work [n*ns]. */
static int sens_step(const Problem *P, const double *y, const double *xn, const double *xp, const double *u,
                     const double *th, const int *sel, int ns, const double *SN, const double *SP, double *Sy,
                     double *lu, double *jnz, double *jth, double *C) {
  int n = P->n, nx = P->nx, j, i;
  double w = u[1];
  double alpha = -(1 + w) * (1 + w) / (1 + 2 * w), beta = w * w / (1 + 2 * w);
  call(bl_jac, PR_JTH, y, xn, xp, u, th, jnz, jth, 0);
  if (lu_factor(P, jnz, lu)) return -2;
  if (beta != 0.0)
    for (i = 0; i < nx * ns; ++i) Sy[i] = -(alpha * SN[i] + beta * SP[i]);
  else
    for (i = 0; i < nx * ns; ++i) Sy[i] = -(alpha * SN[i]);
  memset(Sy + (size_t)nx * ns, 0, sizeof(double) * (size_t)(n - nx) * ns);
  for (j = 0; j < ns; ++j) {
    int col = sel[j];
    if (col < 0) continue; /* a direction of the start state alone (the start SOC): no dR/dth term */
    for (i = P->jth_colptr[col]; i < P->jth_colptr[col + 1]; ++i) Sy[(size_t)P->jth_row[i] * ns + j] -= jth[i];
  }
  lu_solve_multi(P, lu, Sy, C, ns);
  return 0;
}

/* Sensitivities of a converged zero-length solve into Sy (n x ns): the x rows are SN's (the differential states
 * do not move), the z rows S_z = -g_z^-1 (g_x S_x + dg/dth[:, sel]). P0: the zero-length problem (n = nz); xp:
 * any [nx]; jfull, jth: out, the step Jacobians at y for a backward-Euler step of 1 s (the algebraic rows are
 * those of any h; the next step starts from this state: jac_scaled gives its Newton matrix); gnz, gx, gth: work
 * for the algebraic block's; C: work [nz*ns]. The factorisation of g_z stays in lu0 (the next chord matrix). */
static int sens_zero(const Problem *P0, const double *y, const double *xp, const double *u, const double *th,
                     const int *sel, int ns, const double *SN, double *Sy, double *lu0, double *jfull, double *jth,
                     double *gnz, double *gx, double *gth, double *C) {
  int nz = P0->n, nx = P0->nx, j, k, col;
  double *B = Sy + (size_t)nx * ns, u1[4] = {1.0, 0.0, u[2], u[3]};
  call(bl_jac, PR_JTH, y, y, xp, u1, th, jfull, jth, 0);
  gather(jfull, P0->gz_at, P0->jac_nnz, gnz);
  gather(jfull, P0->gx_at, P0->gx_nnz, gx);
  gather(jth, P0->gth_at, P0->jth_nnz, gth);
  if (lu_factor(P0, gnz, lu0)) return -2;
  memcpy(Sy, SN, sizeof(double) * (size_t)nx * ns);
  memset(B, 0, sizeof(double) * (size_t)nz * ns);
  for (col = 0; col < nx; ++col) {
    const double *sc = SN + (size_t)col * ns;
    for (k = P0->gx_colptr[col]; k < P0->gx_colptr[col + 1]; ++k) {
      double v = gx[k], *b = B + (size_t)P0->gx_row[k] * ns;
      for (j = 0; j < ns; ++j) b[j] -= v * sc[j];
    }
  }
  for (j = 0; j < ns; ++j) {
    col = sel[j];
    if (col < 0) continue;
    for (k = P0->jth_colptr[col]; k < P0->jth_colptr[col + 1]; ++k) B[(size_t)P0->jth_row[k] * ns + j] -= gth[k];
  }
  lu_solve_multi(P0, lu0, B, C, ns);
  return 0;
}

/* outputs at a sample: o[5], dV[ns], dT2[ns] (P: the step problem, n = ny) */
static void output(const Problem *P, const double *y, const double *u, const double *th, const int *sel, int ns,
                   const double *Sy, double *o, double *dV, double *dT2, double *vy, double *vth) {
  call(bl_out, PR_OUT, y, u, th, 0, 0, o, 0, 0);
  if (ns) {
    call(bl_outj, PR_OUTJ, y, u, th, 0, 0, vy, vth, 0);
    for (int j = 0; j < ns; ++j) dV[j] = sel[j] < 0 ? 0.0 : vth[sel[j]];
    for (int i = 0; i < P->n; ++i) {
      double v = vy[i];
      if (v != 0.0)
        for (int j = 0; j < ns; ++j) dV[j] += v * Sy[(size_t)i * ns + j];
    }
    for (int j = 0; j < ns; ++j) dT2[j] = Sy[(size_t)P->iT2 * ns + j];
  }
}

/* The right limit at a current change: the algebraic state with the differential states of the left limit y and
 * the current u0[2], into y0. Newton from y (if it fails on the chord matrix of an earlier solve, which belongs to
 * another state and current, again with a fresh Jacobian); if that fails, continuation in the current from I_from,
 * each solve from the last solution, the current step halved when Newton fails and doubled when it converges,
 * down to 1e-4 of the jump. *beyond = 1 when the voltage on the way leaves [limits[0], limits[1]]: the cell cannot
 * carry the new current within its window (a tester stops there), or when no solution was found and the left
 * limit is beyond them (the voltage passed a limit during the step before); o: the outputs there. Returns the
 * Newton iterations of the last solve (>= 0, y0 the solution), -1 (not reached: the voltage-current curve folds
 * before the new current, or Newton failed) or -2 (a vanishing pivot of P0 where the continuation stopped). */
static int right_limit(const Problem *P0, double *y0, const double *y, const double *xp, double *u0, double I_from,
                       const double *th, double *lu0, int *have_lu0, double *R, double *yt, double *Rt, double *jnz,
                       double *jfull, double *c, double tol, int maxit, const double *limits, double *o, double *vy,
                       double *vth, int *beyond) {
  int ny = P0->nx + P0->n, it, solves = 0, singular = 0, chord = *have_lu0;
  double I_to = u0[2], I_at = I_from, dI = 0.125 * (u0[2] - I_from), *ylast;
  System s0 = {P0, 1, y, xp, u0, th, jfull};
  *beyond = 0;
  memcpy(y0, y, sizeof(double) * ny);
  it = newton(&s0, y0, lu0, have_lu0, R, yt, Rt, jnz, c, tol, maxit, 1e-11, 0, 0);
  if (it < 0 && chord) { /* a stale chord matrix can throw the iterate far off (and onto a singular Jacobian) */
    memcpy(y0, y, sizeof(double) * ny);
    *have_lu0 = 0;
    it = newton(&s0, y0, lu0, have_lu0, R, yt, Rt, jnz, c, tol, maxit, 1e-11, 0, 0);
  }
  if (it >= 0) return it;
  singular = it == -2;
  ylast = malloc(sizeof(double) * ny);
  memcpy(ylast, y, sizeof(double) * ny);
  while (I_at != I_to) {
    if (fabs(dI) < 1e-4 * fabs(I_to - I_from) || ++solves > 100) { it = singular ? -2 : -1; break; }
    u0[2] = fabs(I_to - I_at) <= fabs(dI) ? I_to : I_at + dI;
    memcpy(y0, ylast, sizeof(double) * ny);
    it = newton(&s0, y0, lu0, have_lu0, R, yt, Rt, jnz, c, tol, maxit, 1e-11, 0, 0);
    if (it < 0) { /* smaller steps (a far-off iterate can meet a singular Jacobian, too) */
      singular = it == -2;
      dI *= 0.5;
      continue;
    }
    I_at = u0[2];
    memcpy(ylast, y0, sizeof(double) * ny);
    call(bl_out, PR_OUT, y0, u0, th, 0, 0, o, 0, 0);
    if (!(o[0] >= limits[0] && o[0] <= limits[1])) { *beyond = 1; break; }
    dI *= 2.0;
  }
  if (it < 0) { /* the left limit itself beyond the limits: the voltage passed one during the step before */
    u0[2] = I_from;
    call(bl_out, PR_OUT, y, u0, th, 0, 0, o, 0, 0);
    *beyond = !(o[0] >= limits[0] && o[0] <= limits[1]);
  }
  free(ylast);
  return it;
}

/* Interpolated state at time tau (<= 0) from a step's end: quadratic through the starts of this step (tau = -h)
 * and the step before it (tau = -h - hp) and its end (tau = 0), or linear when hp <= 0 (a restart). The same
 * weights on the sensitivity rows (n x ns) when S0 is given. */
static void interpolate(int n, int ns, double tau, double h, double hp, const double *y0, const double *y1,
                        const double *y2, const double *S0, const double *S1, const double *S2, double *yi,
                        double *Si) {
  double l0, l1, l2;
  if (hp > 0.0) {
    double t1 = -h, t2 = -h - hp;
    l0 = (tau - t1) * (tau - t2) / ((0.0 - t1) * (0.0 - t2));
    l1 = (tau - 0.0) * (tau - t2) / ((t1 - 0.0) * (t1 - t2));
    l2 = (tau - 0.0) * (tau - t1) / ((t2 - 0.0) * (t2 - t1));
  } else {
    l0 = 1.0 + tau / h;
    l1 = -tau / h;
    l2 = 0.0;
  }
  for (int i = 0; i < n; ++i) yi[i] = l0 * y0[i] + l1 * y1[i] + (l2 != 0.0 ? l2 * y2[i] : 0.0);
  if (S0)
    for (size_t i = 0; i < (size_t)n * ns; ++i) Si[i] = l0 * S0[i] + l1 * S1[i] + (l2 != 0.0 ? l2 * S2[i] : 0.0);
}

/* The sensitivities of a run in four buffers of n x ns, passed around instead of copied: cur (the start of the
 * next step: the end of the last one, or its right limit), prev (the start of the step before), free (the
 * start of the one before that, read by interpolation, then overwritten), spare (a zero-length solve's result
 * until it replaces cur). */
typedef struct {
  double *cur, *prev, *free, *spare;
} Ring;

static void ring_step(Ring *r) { /* after a step written into free */
  double *t = r->prev;
  r->prev = r->cur;
  r->cur = r->free;
  r->free = t;
}

static void ring_zero(Ring *r) { /* after a zero-length solve written into spare */
  double *t = r->cur;
  r->cur = r->spare;
  r->spare = t;
}

/* the ring's buffers from the caller's state: x rows from S, Sp; z rows from the history SA, SB if any */
static double *ring_open(Ring *r, int n, int nx, int ns, const double *S, const double *Sp, const double *Shist) {
  size_t nsy = (size_t)n * ns, nsx = (size_t)nx * ns;
  double *buf = calloc(4 * nsy, sizeof(double));
  if (!buf) return 0;
  r->cur = buf;
  r->prev = buf + nsy;
  r->free = buf + 2 * nsy;
  r->spare = buf + 3 * nsy;
  if (Shist) {
    memcpy(r->cur, Shist, sizeof(double) * nsy);
    memcpy(r->prev, Shist + nsy, sizeof(double) * nsy);
  }
  memcpy(r->cur, S, sizeof(double) * nsx);
  memcpy(r->prev, Sp, sizeof(double) * nsx);
  return buf;
}

/* back to the caller's arrays: S, Sp (x rows), Sy (all rows of cur), the history SA = cur, SB = prev */
static void ring_close(const Ring *r, int n, int nx, int ns, double *S, double *Sp, double *Sy, double *Shist) {
  size_t nsy = (size_t)n * ns, nsx = (size_t)nx * ns;
  memcpy(S, r->cur, sizeof(double) * nsx);
  memcpy(Sp, r->prev, sizeof(double) * nsx);
  if (Sy) memcpy(Sy, r->cur, sizeof(double) * nsy);
  if (Shist) {
    memcpy(Shist, r->cur, sizeof(double) * nsy);
    memcpy(Shist + nsy, r->prev, sizeof(double) * nsy);
  }
}

/* work arrays shared by bl_run and bl_adapt */
typedef struct {
  double *ynew, *R, *yt, *Rt, *c, *xn, *jnz, *jth, *jfull, *gnz, *gx, *gth, *lu, *lu0, *y0, *ysave, *yi, *Si, *vy,
      *vth, *xp_save;
} Work;

static int work_open(Work *W, const Problem *P, const Problem *P0, int ns) {
  int n = P->n, nx = P->nx;
  size_t nsy = (size_t)n * (ns > 0 ? ns : 1);
  int jnz = P->jac_nnz > P0->jac_nnz ? P->jac_nnz : P0->jac_nnz;
  W->ynew = malloc(sizeof(double) * n);
  W->R = malloc(sizeof(double) * n);
  W->yt = malloc(sizeof(double) * n);
  W->Rt = malloc(sizeof(double) * n);
  W->c = malloc(sizeof(double) * nsy);
  W->xn = malloc(sizeof(double) * nx);
  W->jnz = malloc(sizeof(double) * (jnz + 1));
  W->jth = malloc(sizeof(double) * (P->jth_nnz + 1));
  W->jfull = malloc(sizeof(double) * (P->jac_nnz + 1));
  W->gnz = malloc(sizeof(double) * (P0->jac_nnz + 1));
  W->gx = malloc(sizeof(double) * (P0->gx_nnz + 1));
  W->gth = malloc(sizeof(double) * (P0->jth_nnz + 1));
  W->lu = malloc(sizeof(double) * P->nslot);
  W->lu0 = malloc(sizeof(double) * P0->nslot);
  W->y0 = malloc(sizeof(double) * n);
  W->ysave = malloc(sizeof(double) * n);
  W->yi = malloc(sizeof(double) * n);
  W->Si = malloc(sizeof(double) * nsy);
  W->vy = malloc(sizeof(double) * n);
  W->vth = malloc(sizeof(double) * (P->nth + 1));
  W->xp_save = malloc(sizeof(double) * nx);
  return W->ynew && W->R && W->yt && W->Rt && W->c && W->xn && W->jnz && W->jth && W->jfull && W->gnz && W->gx &&
                 W->gth && W->lu && W->lu0 &&
                 W->y0 && W->ysave && W->yi && W->Si && W->vy && W->vth && W->xp_save
             ? 0
             : -1;
}

static void work_close(Work *W) {
  free(W->ynew); free(W->R); free(W->yt); free(W->Rt); free(W->c); free(W->xn); free(W->jnz); free(W->jth);
  free(W->jfull); free(W->gnz); free(W->gx); free(W->gth); free(W->lu); free(W->lu0); free(W->y0); free(W->ysave); free(W->yi); free(W->Si); free(W->vy);
  free(W->vth); free(W->xp_save);
}

/* Run steps [0, nsteps). State in/out: y[n], xp[nx], S[nx*ns], Sp[nx*ns] (sensitivities of x at the start of the
 * next step and of the one before), Sy[n*ns] (out: the full sensitivities of y); sensitivity arrays row-major
 * (S[i*ns + j]). sched: h, w, I, T_amb, t_end (end time of each step) and emit (whether samples may be written
 * after the step) per step; h = 0: a zero-length solve. Samples: t_samp, I_samp (the current that starts at the
 * sample) for m in [*m, nsamp); a sample at a step's end is written there (the right limit: an algebraic re-solve
 * when I_samp differs from the step's current); a sample inside a step is interpolated (dense: hist holds the
 * starts of the current and the previous step, y and n*ns sensitivities each, kept across calls). P: the pivot
 * program of steps with h > 0; P0: that of zero-length solves (the algebraic block). Returns nsteps on success,
 * else the index of the failed step (and *code: -1 Newton, -2 singular with P, -5 singular with P0; the state is
 * that before the failed step, *m restored), or the number of steps done when sample *m broke a limit (*code = 1,
 * written but not counted) or its right-limit solve failed otherwise (*code = -4). */
int bl_run(const Problem *P, const Problem *P0, int nsteps, const double *h, const double *w, const double *I,
           const double *Tamb, const double *t_end, const int *emit, int nsamp, const double *t_samp,
           const double *I_samp, int *m_io, int dense, double *yhist, double *Shist, const double *th,
           const int *sel, int ns, double tol, int maxit, const double *limits, double *y, double *xp, double *S,
           double *Sp, double *Sy, double *out, double *outdV, double *outdT2, int *code, int *iters) {
  int n = P->n, nx = P->nx, k, have_lu = 0, have_lu0 = 0, emitted1 = 1, emitted2 = 1, have_right = 0;
  int ret = nsteps, jac_right = 0; /* jac_right: W.jfull holds the Jacobian at the right limit y0 (h = 1) */
  Work W;
  Ring ring = {0, 0, 0, 0};
  double *ringbuf = 0;
  /* dense history: start of this step (A) and of the step before (B) */
  double *yA = yhist, *yB = yhist + n;
  if (ensure_work() || work_open(&W, P, P0, ns)) { *code = -3; return 0; }
  if (ns && !(ringbuf = ring_open(&ring, n, nx, ns, S, Sp, dense ? Shist : 0))) {
    work_close(&W);
    *code = -3;
    return 0;
  }
  double *ynew = W.ynew, *y0 = W.y0, *yprev = W.ysave;
  *code = 0;
  *iters = 0;
  for (k = 0; k < nsteps; ++k) {
    double u[4] = {h[k], w[k], I[k], Tamb[k]};
    int it, m0 = *m_io, zero = !(h[k] > 0.0);
    Ring before = ring;
    memcpy(W.xn, y, sizeof(double) * nx);
    /* predictor: after a current step, the right-limit state found for the output; on a continuing BDF2
       step, linear extrapolation of the last two solutions; else the last solution */
    if (have_right) {
      memcpy(ynew, y0, sizeof(double) * n);
    } else if (w[k] > 0.0 && k > 1 && h[k - 1] > 0.0 && I[k - 1] == I[k] && I[k - 2] == I[k] && !emitted2) {
      double r = h[k] / h[k - 1];
      for (int i = 0; i < n; ++i) ynew[i] = y[i] + r * (y[i] - yprev[i]);
    } else {
      memcpy(ynew, y, sizeof(double) * n);
    }
    have_right = 0;
    double eps = 1e-9 * (fabs(t_end[k]) > 1.0 ? fabs(t_end[k]) : 1.0);
    int mm = *m_io;
    while (emit[k] && mm < nsamp && t_samp[mm] <= t_end[k] + eps) ++mm;
    if (mm > *m_io && t_samp[mm - 1] >= t_end[k] - eps && I_samp[mm - 1] != I[k])
      memcpy(W.xp_save, xp, sizeof(double) * nx); /* a right limit at the end: kept to undo this step */
    /* zero-length solves have a pivot program (and chord matrix) of their own */
    System sys = {zero ? P0 : P, zero, W.xn, xp, u, th, W.jfull};
    /* after a right limit: a Newton matrix at it (scaled from the one its sensitivities took, else evaluated) */
    int first = 0;
    if (have_right && !zero) {
      first = jac_right ? 2 : 1;
      if (jac_right) jac_scaled(P, W.jfull, h[k] * (1 + w[k]) / (1 + 2 * w[k]), W.jnz);
    }
    jac_right = 0;
    it = newton(&sys, ynew, zero ? W.lu0 : W.lu, zero ? &have_lu0 : &have_lu, W.R, W.yt, W.Rt, W.jnz, W.c, tol, maxit,
                1e-11, first, 0);
    if (it < 0) { *code = (it == -2 && zero) ? -5 : it; ret = k; break; }
    *iters += it;
    if (ns) {
      int s = zero ? sens_zero(P0, ynew, xp, u, th, sel, ns, ring.cur, ring.spare, W.lu0, W.jfull, W.jth, W.gnz,
                               W.gx, W.gth, W.c)
                   : sens_step(P, ynew, W.xn, xp, u, th, sel, ns, ring.cur, ring.prev, ring.free, W.lu, W.jnz, W.jth,
                               W.c);
      if (s) { *code = zero ? -5 : s; ret = k; break; }
      if (zero) { have_lu0 = 1; ring_zero(&ring); }
      else { have_lu = 1; ring_step(&ring); } /* the exact Jacobian at the solution is the next chord matrix */
    }
    if (!zero) memcpy(xp, W.xn, sizeof(double) * nx);
    memcpy(yprev, y, sizeof(double) * n);
    memcpy(y, ynew, sizeof(double) * n);
    int stop = 0, emitted = 0;
    while (emit[k] && *m_io < nsamp && t_samp[*m_io] <= t_end[k] + eps) {
      int m = *m_io;
      double *o = out + (size_t)5 * m;
      double tau = t_samp[m] - t_end[k];
      emitted = 1;
      if (tau < -eps) {
        /* inside the step (the current is the step's): interpolated from the history */
        if (!dense) { *code = -3; ret = k; stop = 1; break; }
        double hp = w[k] > 0.0 ? h[k] / w[k] : 0.0;
        interpolate(n, ns, tau, h[k], hp, y, yA, yB, ring.cur, ring.prev, ring.free, W.yi, W.Si);
        output(P, W.yi, u, th, sel, ns, W.Si, o, outdV + (size_t)m * ns, outdT2 + (size_t)m * ns, W.vy, W.vth);
      } else if (I_samp[m] == I[k]) {
        output(P, y, u, th, sel, ns, ring.cur, o, outdV + (size_t)m * ns, outdT2 + (size_t)m * ns, W.vy, W.vth);
      } else {
        /* right limit: algebraic re-solve with the new current (a zero-length step) */
        double u0[4] = {0.0, 0.0, I_samp[m], Tamb[k]};
        int beyond;
        it = right_limit(P0, y0, y, xp, u0, I[k], th, W.lu0, &have_lu0, W.R, W.yt, W.Rt, W.jnz, W.jfull, W.c, tol,
                         maxit, limits, o, W.vy, W.vth, &beyond);
        jac_right = 0;
        /* a voltage beyond the limits on the way: the cell cannot carry the new current (a limit, not a solver
           failure; reported as one with the failed right limits, the sample not written) */
        if (beyond) { *code = -4; ret = k + 1; stop = 1; break; }
        if (it >= 0 && ns &&
            sens_zero(P0, y0, xp, u0, th, sel, ns, ring.cur, ring.spare, W.lu0, W.jfull, W.jth, W.gnz, W.gx, W.gth,
                      W.c))
          it = -2;
        if (it == -2) { /* a vanishing pivot: undo the step, so the caller can re-analyse P0 and redo it */
          memcpy(y, yprev, sizeof(double) * n);
          memcpy(xp, W.xp_save, sizeof(double) * nx);
          ring = before;
          *m_io = m0;
          *code = -5;
          ret = k;
          stop = 1;
          break;
        }
        /* the step itself converged: the state has advanced, so a failure here ends the run */
        if (it < 0) { *code = -4; ret = k + 1; stop = 1; break; }
        if (ns) { have_lu0 = 1; ring_zero(&ring); jac_right = 1; }
        output(P, y0, u0, th, sel, ns, ring.cur, o, outdV + (size_t)m * ns, outdT2 + (size_t)m * ns, W.vy, W.vth);
        have_right = 1;
      }
      /* limits [V_min, V_max, T_max]: stop at the first sample beyond them (or with an empty/full surface) */
      if (!(o[0] >= limits[0] && o[0] <= limits[1] && o[2] <= limits[2] && o[3] > 0.0 && o[4] < 1.0)) {
        *code = 1;
        ret = k + 1;
        stop = 1;
        break;
      }
      ++*m_io;
    }
    if (stop) break;
    emitted2 = emitted1;
    emitted1 = emitted;
    if (dense) { /* the start of the next step: the right limit where one was taken */
      double *tmp = yB; yB = yA; yA = tmp;
      memcpy(yA, have_right ? y0 : y, sizeof(double) * n);
    }
  }
  /* the history goes back in its fixed places for the next call */
  if (dense && yA != yhist) {
    memcpy(W.yi, yA, sizeof(double) * n); memcpy(yA, yB, sizeof(double) * n); memcpy(yB, W.yi, sizeof(double) * n);
  }
  if (ns) ring_close(&ring, n, nx, ns, S, Sp, Sy, dense ? Shist : 0);
  free(ringbuf);
  work_close(&W);
  return ret;
}

/* Error-controlled steps over segments of constant current (variable-step BDF2, the step sizes chosen as the
 * solution goes). Segment k: duration seg_h[k] [s] ending at seg_t[k] on the samples' clock, current seg_I[k],
 * seg_w[k] = 0 to restart with backward Euler after a current jump, else continue the BDF2 history. A step's local
 * error is estimated by the distance of its solution from the quadratic extrapolation of the last three (the
 * differential states, max norm, weights 1/(atol + rtol |x|)), scaled by h/(h + h1 + h2); a step with an estimate
 * above 1 is redone with a smaller h, an accepted one sets the next h (at most x growth, at most hmax). The first
 * two steps of a restart are dt_first and 2 dt_first. Samples are written as in bl_run (interpolated inside
 * steps, right limits at segment ends). Accepted steps are recorded in plan_h/w/I/t (capacity plan_cap, count
 * *plan_n) so that bl_run can replay them (for sensitivities at other theta, as finite differences need).
 * ctl (in/out, kept across calls): [0] t (time reached), [1] next h, [2] h1 (last step), [3] h2 (the one before),
 * [4] accepted steps in this segment, [5] 1 while inside segment 0 of this call, [6] 1 when called again after a
 * pivot re-analysis (cleared at the first accepted step); settings: adapt[5] = rtol, atol,
 * hmax, growth, dt_first. yhist: 3n (starts of this step, the previous and the one before), Shist: 2 n ns.
 * Returns segments completed; *code as bl_run, plus -6 (the plan is full: call again) and -1 (Newton failed at a
 * step below 1e-6 s); the state is always that of the last accepted step. */
int bl_adapt(const Problem *P, const Problem *P0, int nseg, const double *seg_h, const double *seg_w,
             const double *seg_I, const double *seg_t, double Tamb, int nsamp, const double *t_samp,
             const double *I_samp, int *m_io, double *yhist, double *Shist, double *ctl, const double *adapt,
             const double *th, const int *sel, int ns, double tol, int maxit, const double *limits, double *y,
             double *xp, double *S, double *Sp, double *Sy, double *out, double *outdV, double *outdT2,
             double *plan_h, double *plan_w, double *plan_I, double *plan_t, int plan_cap, int *plan_n, int *code,
             int *iters) {
  int n = P->n, nx = P->nx, k, have_lu = 0, have_lu0 = 0;
  double rtol = adapt[0], atol = adapt[1], hmax = adapt[2], growth = adapt[3], dt_first = adapt[4];
  /* Newton converged well inside the local error allowed (a chord update 1 % of rtol) */
  double ntol = 0.01 * rtol > 1e-11 ? 0.01 * rtol : 1e-11;
  double *yA = yhist, *yB = yhist + n, *yC = yhist + 2 * (size_t)n;
  int ret = nseg, have_right = 0, jac_right = 0; /* jac_right: W.jfull holds the Jacobian at y0 (h = 1) */
  Work W;
  Ring ring = {0, 0, 0, 0};
  double *ringbuf = 0;
  if (ensure_work() || work_open(&W, P, P0, ns)) { *code = -3; return 0; }
  if (ns && !(ringbuf = ring_open(&ring, n, nx, ns, S, Sp, Shist))) {
    work_close(&W);
    *code = -3;
    return 0;
  }
  double *ynew = W.ynew, *xn = W.xn, *y0 = W.y0, *ysave = W.ysave;
  *code = 0;
  *iters = 0;
  for (k = 0; k < nseg; ++k) {
    double t_e = seg_t[k], t_s = seg_t[k] - seg_h[k];
    double eps = 1e-9 * (fabs(t_e) > 1.0 ? fabs(t_e) : 1.0);
    if (!(k == 0 && ctl[5] > 0.0)) { /* a fresh segment (else: resumed inside segment 0) */
      ctl[0] = t_s;
      if (seg_w[k] == 0.0) { ctl[1] = dt_first; ctl[4] = 0.0; }
    }
    ctl[5] = 1.0;
    while (ctl[0] < t_e - eps) {
      double t = ctl[0], remaining = t_e - t, h = ctl[1] < hmax ? ctl[1] : hmax, err = 0.0;
      int nseg_steps = (int)ctl[4], it;
      if (remaining <= 1.2 * h) h = remaining;
      else if (remaining <= 2.0 * h) h = 0.5 * remaining;
      double w = nseg_steps == 0 ? 0.0 : h / ctl[2];
      if (w > 2.4) { h = 2.4 * ctl[2]; w = 2.4; }
      double u[4] = {h, w, seg_I[k], Tamb};
      memcpy(xn, y, sizeof(double) * nx);
      /* predictor: the quadratic (after two steps of this segment) or linear (after one) extrapolation of the
         history, which the error estimate below measures the solution against; at a restart the right limit */
      double l0 = 1.0, l1 = 0.0, l2 = 0.0;
      if (nseg_steps >= 2) {
        double h1 = ctl[2], h2 = ctl[3], t1 = -h1, t2 = -h1 - h2;
        l0 = (h - t1) * (h - t2) / (t1 * t2);
        l1 = h * (h - t2) / (t1 * (t1 - t2));
        l2 = h * (h - t1) / (t2 * (t2 - t1));
      } else if (nseg_steps == 1) {
        l0 = 1.0 + h / ctl[2];
        l1 = -h / ctl[2];
      }
      if (nseg_steps >= 1)
        for (int i = 0; i < n; ++i) ynew[i] = l0 * yA[i] + l1 * yB[i] + (l2 != 0.0 ? l2 * yC[i] : 0.0);
      else if (have_right) memcpy(ynew, y0, sizeof(double) * n);
      /* resumed after a pivot re-analysis (ctl[6] = 1) at a restart: the start of this step kept in the history
         (the right limit where one was taken; y0 is not kept across calls, and y is the left limit, at the old
         current, from which Newton can fail at any step size after a large current change) */
      else if (ctl[6] > 0.0 && *plan_n > 0) memcpy(ynew, yA, sizeof(double) * n);
      else memcpy(ynew, y, sizeof(double) * n);
      System sys = {P, 0, xn, xp, u, th, W.jfull};
      /* the first step after a right limit: a Newton matrix at it (scaled from the one its sensitivities took) */
      int first = 0;
      if (nseg_steps == 0 && have_right) {
        first = jac_right ? 2 : 1;
        if (jac_right) jac_scaled(P, W.jfull, h * (1 + w) / (1 + 2 * w), W.jnz);
      }
      it = newton(&sys, ynew, W.lu, &have_lu, W.R, W.yt, W.Rt, W.jnz, W.c, tol, maxit, ntol, first, ns == 0);
      if (it == -2) { *code = -2; ret = k; goto done; }
      if (it < 0) { /* a smaller step from the same state */
        if (h < 1e-6) { *code = -1; ret = k; goto done; }
        ctl[1] = 0.25 * h;
        continue;
      }
      *iters += it;
      if (nseg_steps >= 2) {
        /* the distance from the quadratic extrapolation through the starts of the last two steps and this one */
        double scale = h / (h + ctl[2] + ctl[3]);
        for (int i = 0; i < nx; ++i) {
          double pred = l0 * yA[i] + l1 * yB[i] + l2 * yC[i];
          double e = fabs(ynew[i] - pred) * scale / (atol + rtol * fabs(ynew[i]));
          if (!(e <= err)) err = e;
        }
        if (!(err <= 1.0)) { /* rejected: redo smaller */
          /* at most 0.8 h: the split rules (h = remaining within 1.2 h) must not bring the same step back */
          double f = 0.9 * pow(err, -1.0 / 3.0);
          ctl[1] = h * (f > 0.8 ? 0.8 : f > 0.2 ? f : 0.2);
          if (ctl[1] < 1e-6) { *code = -1; ret = k; goto done; }
          continue;
        }
      }
      if (*plan_n >= plan_cap) { *code = -6; ret = k; goto done; }
      /* accepted */
      ctl[6] = 0.0;
      double t_end = (h == remaining) ? t_e : t + h;
      int m0 = *m_io;
      memcpy(W.xp_save, xp, sizeof(double) * nx); /* to undo the step if its right limit meets a vanishing pivot */
      memcpy(ysave, y, sizeof(double) * n);
      Ring before = ring;
      if (ns) {
        int s = sens_step(P, ynew, xn, xp, u, th, sel, ns, ring.cur, ring.prev, ring.free, W.lu, W.jnz, W.jth, W.c);
        if (s) { *code = s; ret = k; goto done; }
        have_lu = 1;
        ring_step(&ring);
      }
      memcpy(xp, xn, sizeof(double) * nx);
      memcpy(y, ynew, sizeof(double) * n);
      have_right = jac_right = 0;
      int stop = 0;
      while (*m_io < nsamp && t_samp[*m_io] <= t_end + eps) {
        int m = *m_io;
        double *o = out + (size_t)5 * m;
        double tau = t_samp[m] - t_end;
        if (tau < -eps) {
          interpolate(n, ns, tau, h, w > 0.0 ? h / w : 0.0, y, yA, yB, ring.cur, ring.prev, ring.free, W.yi, W.Si);
          output(P, W.yi, u, th, sel, ns, W.Si, o, outdV + (size_t)m * ns, outdT2 + (size_t)m * ns, W.vy, W.vth);
        } else if (I_samp[m] == seg_I[k]) {
          output(P, y, u, th, sel, ns, ring.cur, o, outdV + (size_t)m * ns, outdT2 + (size_t)m * ns, W.vy, W.vth);
        } else {
          double u0[4] = {0.0, 0.0, I_samp[m], Tamb};
          int beyond;
          it = right_limit(P0, y0, y, xp, u0, seg_I[k], th, W.lu0, &have_lu0, W.R, W.yt, W.Rt, W.jnz, W.jfull, W.c,
                           tol, maxit, limits, o, W.vy, W.vth, &beyond);
          jac_right = 0;
          if (beyond) { *code = -4; stop = 1; break; }
          if (it >= 0 && ns &&
              sens_zero(P0, y0, xp, u0, th, sel, ns, ring.cur, ring.spare, W.lu0, W.jfull, W.jth, W.gnz, W.gx, W.gth,
                        W.c))
            it = -2;
          if (it == -2) { /* undo the step: the caller re-analyses P0 and calls again */
            memcpy(y, ysave, sizeof(double) * n);
            memcpy(xp, W.xp_save, sizeof(double) * nx);
            ring = before;
            *m_io = m0;
            *code = -5;
            ret = k;
            goto done;
          }
          if (it < 0) { *code = -4; stop = 1; break; }
          if (ns) { have_lu0 = 1; ring_zero(&ring); jac_right = 1; }
          output(P, y0, u0, th, sel, ns, ring.cur, o, outdV + (size_t)m * ns, outdT2 + (size_t)m * ns, W.vy, W.vth);
          have_right = 1;
        }
        if (!(o[0] >= limits[0] && o[0] <= limits[1] && o[2] <= limits[2] && o[3] > 0.0 && o[4] < 1.0)) {
          *code = 1;
          stop = 1;
          break;
        }
        ++*m_io;
      }
      plan_h[*plan_n] = h; plan_w[*plan_n] = w; plan_I[*plan_n] = seg_I[k]; plan_t[*plan_n] = t_end;
      ++*plan_n;
      /* history: the start of the next step (the right limit where one was taken) */
      memcpy(yC, yB, sizeof(double) * n);
      memcpy(yB, yA, sizeof(double) * n);
      memcpy(yA, have_right ? y0 : y, sizeof(double) * n);
      ctl[0] = t_end;
      ctl[3] = ctl[2];
      ctl[2] = h;
      ctl[4] = nseg_steps + 1;
      if (nseg_steps < 2) ctl[1] = 2.0 * h;
      else {
        double f = err > 0.0 ? 0.9 * pow(err, -1.0 / 3.0) : growth;
        if (f >= 1.0 && f < 1.5) f = 1.0; /* keep h (and so the chord matrix) unless it can grow by half */
        ctl[1] = h * (f < growth ? f : growth);
      }
      if (stop) { ret = k; goto done; }
    }
    ctl[5] = 0.0;
  }
done:
  if (ns) ring_close(&ring, n, nx, ns, S, Sp, Sy, Shist);
  free(ringbuf);
  work_close(&W);
  return ret;
}
