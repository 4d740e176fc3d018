/* One tick of the online conformance monitor (paper Theorem 1, checked tick by tick).
 *
 * A compiled copy of reachset_ros.conformance.monitor.Monitor._tick_numpy for the per-joint LWA-4P
 * plant with the "fd" or "lsq" initial-state estimator. Every floating-point operation is the one
 * numpy performs there, in the same order, each rounded on its own: this file must be
 * compiled with -ffp-contract=off (no fused multiply-add) and without -ffast-math, so
 * that the verdicts stay bitwise equal to `reachset check` (test/test_monitor_kernel.py
 * compares the two paths bit for bit).
 *
 * Loaded with ctypes by reachset_ros/conformance/kernels.py (with reachset_sweep_block below);
 * the state struct is mirrored by _TickState in reachset_ros/conformance/monitor.py. No
 * Python API is used.
 */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

typedef struct {
    /* sizes */
    int64_t n;        /* states */
    int64_t J;        /* joints */
    int64_t S;        /* ring slots = k* + 1 */
    int64_t H;        /* estimator history */
    double dt;
    /* plant (dense, row-major): A (n x n), B (n x 1), C (1 x n), D (1 x 1); N the 1x1 normal */
    const double *A, *B, *C, *D;
    int64_t has_d;
    double N;
    const double *dp, *dm;    /* (J*S) offsets per joint and k */
    /* state */
    double *X0, *X1;          /* two (n x J*S) buffers; cur says which holds X */
    int64_t *cur;
    int64_t *start, *ages;    /* (J*S) */
    uint8_t *active;          /* (J*S) */
    double *y_hist, *u_hist;  /* (J x (H+1)), oldest first */
    int64_t *in_segment;      /* (J) */
    int64_t *tick_index, *last_stamp, *has_last;
    double *Y, *Ny, *U, *BU;  /* scratch (J*S), BU is (n x J*S) */
    /* inputs */
    const double *y_in, *u_in;
    /* outputs (J) */
    double *margin, *deviation, *bound;
    int64_t *checked, *step, *start_tick;
    int8_t *status;           /* 0 ok, 1 violation, 2 invalid, 3 gap_reset */
    int64_t *longest;         /* largest step k checked this tick (-1: none) */
    double *use;              /* set use: largest |N y_a| / bound over the checks (NaN: none) */
    /* the initial-state estimator: 0 "fd"; 1 "lsq" with weights EP (n x (H-1)) on the samples
     * y[m-H+2..m] and ER (n x H) on the inputs u[m-H..m-1] (estimators.lsq_weights) */
    int64_t est_kind;
    const double *EP, *ER;
} tick_state;

/* out[c] = sum over the nonzero entries a of row `row` of M (n_cols wide), in order, of
 * a * X[j][c] (a factor 1.0 taken as X[j][c] itself), the first term assigned, not added:
 * exactly reachset_ros.conformance.kernels.matvec_into. */
static void row_matvec(const double *Mrow, int64_t ncols, const double *X, int64_t N, double *out)
{
    int first = 1;
    for (int64_t j = 0; j < ncols; ++j) {
        double a = Mrow[j];
        if (a == 0.0)
            continue;
        const double *x = X + j * N;
        if (first) {
            if (a == 1.0)
                memcpy(out, x, (size_t)N * sizeof(double));
            else
                for (int64_t c = 0; c < N; ++c) out[c] = a * x[c];
            first = 0;
        } else {
            if (a == 1.0)
                for (int64_t c = 0; c < N; ++c) out[c] = out[c] + x[c];
            else
                for (int64_t c = 0; c < N; ++c) out[c] = out[c] + a * x[c];
        }
    }
    if (first)
        for (int64_t c = 0; c < N; ++c) out[c] = 0.0;
}

static void drop_row(tick_state *s, int64_t j)
{
    for (int64_t k = 0; k < s->S; ++k) {
        s->start[j * s->S + k] = -1;
        s->active[j * s->S + k] = 0;
    }
    s->in_segment[j] = 0;
}

/* numpy's argmin: index of the first minimum; a NaN counts as the minimum (first NaN). */
static int64_t argmin(const double *v, int64_t n)
{
    int64_t best = 0;
    double bv = v[0];
    if (isnan(bv))
        return 0;
    for (int64_t i = 1; i < n; ++i) {
        if (isnan(v[i]))
            return i;
        if (v[i] < bv) {
            bv = v[i];
            best = i;
        }
    }
    return best;
}

/* The layout of tick_state above and the exported functions' signatures: kernels.TICK_ABI must
 * equal it, or kernels.py does not use this library (a stale build of an older layout would leave
 * fields unwritten, or lack a function). 2: `use` added; 3: reachset_sweep_extremes and
 * reachset_monitor_ticks added; 4: the "lsq" estimator (est_kind, EP, ER). */
int64_t reachset_tick_abi(void)
{
    return 4;
}

/* The smallest use reported for a violated check (set_use._ABOVE_ONE): nextafter(1.0, 2.0). */
#define ABOVE_ONE 1.0000000000000002

/* set_use._ratio of one half-space: dev / bound where the bound is positive; a non-positive
 * bound counts 1 when respected and infinity when violated; a NaN counts infinity. */
static inline double use_ratio(double dev, double bound, int violated)
{
    double r = bound > 0 ? dev / bound : (violated ? INFINITY : 1.0);
    return isnan(r) ? INFINITY : r;
}

/* set_use.check_use of one check (one half-space pair, N = [N]): the set use of the check,
 * above 1 exactly when it is violated; -0.0 made +0.0 as there (no NaN is returned). */
static inline double check_use(double Ny, double dp, double dm, double mp, double mm)
{
    int vp = !(mp >= 0), vm = !(mm >= 0);
    double rp = use_ratio(Ny, dp, vp), rm = use_ratio(-Ny, dm, vm);
    double r = rp >= rm ? rp : rm;
    if (vp || vm)
        r = r >= ABOVE_ONE ? r : ABOVE_ONE;
    else
        r = r <= 1.0 ? r : 1.0;
    return r + 0.0;
}

/* Returns 1 if every joint is "ok", else 0. `mp`, `mm`: scratch of J*S doubles. */
int64_t reachset_monitor_tick(tick_state *s, int64_t stamp_ns, double *mp, double *mm)
{
    const int64_t n = s->n, J = s->J, S = s->S, H = s->H, NS = J * S, W = H + 1;
    int64_t t = ++(*s->tick_index);
    int gap = 0, all_valid = 1;
    double y[64], u[64];
    uint8_t valid[64];
    if (J > 64)
        return -1;

    if (*s->has_last) {
        double step = (double)(stamp_ns - *s->last_stamp) * 1e-9;
        if (!(0.5 * s->dt <= step && step <= 1.5 * s->dt)) {
            gap = 1;
            for (int64_t j = 0; j < J; ++j) drop_row(s, j);
        }
    }
    *s->last_stamp = stamp_ns;
    *s->has_last = 1;
    for (int64_t j = 0; j < J; ++j) {
        valid[j] = isfinite(s->y_in[j]) && isfinite(s->u_in[j]);
        y[j] = valid[j] ? s->y_in[j] : 0.0;
        u[j] = valid[j] ? s->u_in[j] : 0.0;
        if (!valid[j]) {
            all_valid = 0;
            drop_row(s, j);
        }
    }
    for (int64_t j = 0; j < J; ++j) {
        double *yh = s->y_hist + j * W, *uh = s->u_hist + j * W;
        memmove(yh, yh + 1, (size_t)H * sizeof(double));
        memmove(uh, uh + 1, (size_t)H * sizeof(double));
        yh[H] = y[j];
        uh[H] = u[j];
        if (valid[j])
            s->in_segment[j] += 1;
    }
    const int64_t slot = t % S;
    double *X = *s->cur ? s->X1 : s->X0;
    double *Xn = *s->cur ? s->X0 : s->X1;
    for (int64_t i = 0; i < NS; ++i) s->ages[i] += 1;
    for (int64_t j = 0; j < J; ++j) {
        int64_t c = j * S + slot;
        s->active[c] = 0;
        if (s->in_segment[j] > H) {
            const double *yh = s->y_hist + j * W, *uh = s->u_hist + j * W;
            if (s->est_kind == 1) {
                /* the "lsq" estimate, reachset_ros.conformance.estimators._lsq, same operation order */
                for (int64_t i = 0; i < n; ++i) {
                    double acc = 0.0;
                    for (int64_t q = 0; q < H - 1; ++q)
                        if (s->EP[i * (H - 1) + q] != 0.0) acc = acc + s->EP[i * (H - 1) + q] * yh[2 + q];
                    for (int64_t q = 0; q < H; ++q)
                        if (s->ER[i * H + q] != 0.0) acc = acc + s->ER[i * H + q] * uh[q];
                    X[i * NS + c] = acc;
                }
                s->start[c] = t;
                s->ages[c] = 0;
                s->active[c] = 1;
                continue;
            }
            /* the "fd" estimate, reachset_ros.conformance.estimators.fd_formula, same operation order */
            double dt = s->dt;
            double ym = yh[3], ym1 = yh[2], u1 = uh[2], u2 = uh[1], u3 = uh[0];
            double v2 = (ym - ym1) / dt - 0.5 * dt * u3;
            double v1 = v2 + dt * u3;
            X[0 * NS + c] = ym;
            X[1 * NS + c] = ym + dt * v1 + 0.5 * dt * dt * u2;
            X[2 * NS + c] = v1 + dt * u2;
            X[3 * NS + c] = 0.0;
            X[4 * NS + c] = u1;
            s->start[c] = t;
            s->ages[c] = 0;
            s->active[c] = 1;
        }
    }
    for (int64_t j = 0; j < J; ++j)
        for (int64_t k = 0; k < S; ++k) s->U[j * S + k] = u[j];
    /* nominal output C X (+ D U) and the deviation's normal component N (y - y*) */
    row_matvec(s->C, n, X, NS, s->Y);
    if (s->has_d) {
        double d = s->D[0];
        double du;
        for (int64_t c = 0; c < NS; ++c) {
            du = (d == 0.0) ? 0.0 : (d == 1.0 ? s->U[c] : d * s->U[c]);
            s->Y[c] = s->Y[c] + du;
        }
    }
    for (int64_t j = 0; j < J; ++j)
        for (int64_t k = 0; k < S; ++k) {
            int64_t c = j * S + k;
            double ya = y[j] - s->Y[c];
            s->Ny[c] = (s->N == 0.0) ? 0.0 : (s->N == 1.0 ? ya : s->N * ya);
        }
    int64_t all_ok = all_valid && !gap;
    for (int64_t j = 0; j < J; ++j) {
        int64_t cnt = 0, longest = -1;
        double use = NAN;
        for (int64_t k = 0; k < S; ++k) {
            int64_t c = j * S + k;
            int64_t a = s->ages[c] < S - 1 ? s->ages[c] : S - 1;
            if (s->active[c]) {
                mp[c] = s->dp[j * S + a] - s->Ny[c];
                mm[c] = s->dm[j * S + a] + s->Ny[c];
                double r = check_use(s->Ny[c], s->dp[j * S + a], s->dm[j * S + a], mp[c], mm[c]);
                use = (isnan(use) || r > use) ? r : use;     /* numpy's fmax */
                ++cnt;
                if (s->ages[c] > longest)
                    longest = s->ages[c];
            } else {
                mp[c] = INFINITY;
                mm[c] = INFINITY;
            }
        }
        int64_t jp = argmin(mp + j * S, S), jm = argmin(mm + j * S, S);
        double vp = mp[j * S + jp], vm = mm[j * S + jm];
        int use_p = vp <= vm;
        int64_t col = use_p ? jp : jm;
        double margin = use_p ? vp : vm;
        /* fail closed: a NaN among the margins (argmin returns the first) is no margin at all */
        if (isnan(vp) || isnan(vm))
            margin = NAN;
        int64_t c = j * S + col;
        int64_t k = s->ages[c] < S - 1 ? s->ages[c] : S - 1;
        s->checked[j] = cnt;
        s->longest[j] = longest;
        s->use[j] = use;
        s->margin[j] = valid[j] ? margin : -INFINITY;
        s->step[j] = cnt > 0 ? k : -1;
        s->start_tick[j] = cnt > 0 ? s->start[c] : -1;
        s->deviation[j] = cnt > 0 ? (use_p ? s->Ny[c] : -s->Ny[c]) : 0.0;
        s->bound[j] = cnt > 0 ? (use_p ? s->dp[j * S + k] : s->dm[j * S + k]) : 0.0;
        if (!valid[j])
            s->status[j] = 2;
        else if (!(margin >= 0))
            s->status[j] = 1;
        else
            s->status[j] = gap ? 3 : 0;
        if (s->status[j] != 0)
            all_ok = 0;
    }
    /* advance: X <- A X + B U, as kernels.advance (A part, then + the B part) */
    for (int64_t i = 0; i < n; ++i) {
        row_matvec(s->A + i * n, n, X, NS, Xn + i * NS);
        row_matvec(s->B + i, 1, s->U, NS, s->BU);
        double *o = Xn + i * NS;
        for (int64_t c = 0; c < NS; ++c) o[c] = o[c] + s->BU[c];
    }
    *s->cur = !*s->cur;
    return all_ok;
}

/* reachset_monitor_tick over T ticks in a row (a replayed recording): tick t reads y = Y[t*J ..],
 * u = U[t*J ..] and the stamp stamps[t]; per tick and joint it stores the status, the number of
 * test cases checked and the set use (status/checked/use: T x J), and per tick its own duration in
 * nanoseconds (ns: T; CLOCK_MONOTONIC around the tick). The very function the monitor node calls
 * once per message, so the verdicts are the node's. y_in and u_in of the state are restored.
 * Returns the number of ticks with some joint not "ok", or -1 if a tick failed. */
int64_t reachset_monitor_ticks(tick_state *s, int64_t T, const int64_t *stamps, const double *Y, const double *U,
                               double *mp, double *mm, int8_t *status, int64_t *checked, double *use, int64_t *ns)
{
    const double *y_in = s->y_in, *u_in = s->u_in;
    const int64_t J = s->J;
    int64_t not_ok = 0;
    struct timespec a, b;
    for (int64_t t = 0; t < T; ++t) {
        s->y_in = Y + t * J;
        s->u_in = U + t * J;
        clock_gettime(CLOCK_MONOTONIC, &a);
        int64_t ok = reachset_monitor_tick(s, stamps[t], mp, mm);
        clock_gettime(CLOCK_MONOTONIC, &b);
        if (ok < 0) {
            not_ok = -1;
            break;
        }
        not_ok += !ok;
        ns[t] = (int64_t)(b.tv_sec - a.tv_sec) * 1000000000 + (b.tv_nsec - a.tv_nsec);
        memcpy(status + t * J, s->status, (size_t)J * sizeof *status);
        memcpy(checked + t * J, s->checked, (size_t)J * sizeof *checked);
        memcpy(use + t * J, s->use, (size_t)J * sizeof *use);
    }
    s->y_in = y_in;
    s->u_in = u_in;
    return not_ok;
}

/* ------------------------------------------------------------------ the batch sweep */

/* A matrix's nonzero entries per row, in row-major order (zeros are skipped, as in
 * kernels.matvec_plan; a factor 1.0 is multiplied, which is exact: 1.0 * x == x). */
typedef struct {
    int64_t rows;
    int64_t start[65];   /* row r: entries start[r] .. start[r+1]-1 */
    int64_t col[64 * 64];
    double coef[64 * 64];
} plan_t;

static void make_plan(plan_t *p, const double *M, int64_t rows, int64_t cols)
{
    int64_t e = 0;
    p->rows = rows;
    for (int64_t r = 0; r < rows; ++r) {
        p->start[r] = e;
        for (int64_t c = 0; c < cols; ++c)
            if (M[r * cols + c] != 0.0) {
                p->col[e] = c;
                p->coef[e] = M[r * cols + c];
                ++e;
            }
    }
    p->start[rows] = e;
}

/* one column of kernels.matvec_into: first term assigned, the others added in order,
 * an empty row gives 0.0 */
static inline double plan_dot(const plan_t *p, int64_t r, const double *v)
{
    int64_t a = p->start[r], b = p->start[r + 1];
    if (a == b)
        return 0.0;
    double out = p->coef[a] * v[p->col[a]];
    for (int64_t e = a + 1; e < b; ++e) out = out + p->coef[e] * v[p->col[e]];
    return out;
}

/* out[i] = row r of the plan applied to the columns v[c][i], i < m: first term assigned,
 * the others added in order, an empty row gives 0.0 (kernels.matvec_into). */
static inline void plan_row(const plan_t *p, int64_t r, double *const *v, int64_t m, double *restrict out)
{
    int64_t a = p->start[r], b = p->start[r + 1];
    if (a == b) {
        for (int64_t i = 0; i < m; ++i) out[i] = 0.0;
        return;
    }
    const double c0 = p->coef[a];
    const double *restrict v0 = v[p->col[a]];
    for (int64_t i = 0; i < m; ++i) out[i] = c0 * v0[i];
    for (int64_t e = a + 1; e < b; ++e) {
        const double c = p->coef[e];
        const double *restrict ve = v[p->col[e]];
        for (int64_t i = 0; i < m; ++i) out[i] = out[i] + c * ve[i];
    }
}

#define TILE 256

/* One block of kernels.sweep: for the test cases i < M (columns of X, initial states
 * estimated by the caller) and k = 0..min(rem[i] - 1, horizon), with t = starts[i] + k,
 *
 *     ya[k][r][i] = y[t][r] - ((C x)[r] (+ (D u[t])[r] if has_d)),   x <- A x + B u[t],
 *
 * the operations of kernels.predict_output and kernels.advance on each column, in
 * their order (columns are independent; tiles of TILE columns keep the data in cache).
 * X (n x M) is overwritten; ya is (horizon + 1) x ny x M, entries of test cases that ended
 * before k are left untouched. rem must be sorted in descending order.
 * Returns 0, or -1 if a size exceeds 64. */
int64_t reachset_sweep_block(const double *A, const double *B, const double *C, const double *D,
                             int64_t has_d, int64_t n, int64_t nu, int64_t ny,
                             const double *y, const double *u, const int64_t *starts, const int64_t *rem,
                             int64_t M, int64_t horizon, double *X, double *ya)
{
    static __thread plan_t pA, pB, pC, pD;
    static __thread double xs[2][64][TILE], us[64][TILE], tmp[TILE];
    double *xv[64], *xn[64], *uv[64];
    if (n > 64 || nu > 64 || ny > 64)
        return -1;
    make_plan(&pA, A, n, n);
    make_plan(&pB, B, n, nu);
    make_plan(&pC, C, ny, n);
    make_plan(&pD, D, ny, nu);
    for (int64_t c = 0; c < nu; ++c) uv[c] = us[c];
    for (int64_t i0 = 0; i0 < M; i0 += TILE) {
        int64_t m = M - i0 < TILE ? M - i0 : TILE;
        int cur = 0;
        for (int64_t s = 0; s < n; ++s) memcpy(xs[cur][s], X + s * M + i0, (size_t)m * sizeof(double));
        for (int64_t k = 0; k <= horizon; ++k) {
            while (m > 0 && rem[i0 + m - 1] <= k) --m;      /* rem descending: drop ended test cases */
            if (m == 0)
                break;
            for (int64_t s = 0; s < n; ++s) {
                xv[s] = xs[cur][s];
                xn[s] = xs[!cur][s];
            }
            for (int64_t c = 0; c < nu; ++c)
                for (int64_t i = 0; i < m; ++i) us[c][i] = u[(starts[i0 + i] + k) * nu + c];
            for (int64_t r = 0; r < ny; ++r) {
                double *restrict out = ya + (k * ny + r) * M + i0;
                plan_row(&pC, r, xv, m, out);                  /* y* = C x */
                if (has_d) {
                    plan_row(&pD, r, uv, m, tmp);              /* + D u */
                    for (int64_t i = 0; i < m; ++i) out[i] = out[i] + tmp[i];
                }
                for (int64_t i = 0; i < m; ++i) out[i] = y[(starts[i0 + i] + k) * ny + r] - out[i];
            }
            for (int64_t s = 0; s < n; ++s) {                  /* x <- A x + B u */
                plan_row(&pA, s, xv, m, xn[s]);
                plan_row(&pB, s, uv, m, tmp);
                for (int64_t i = 0; i < m; ++i) xn[s][i] = xn[s][i] + tmp[i];
            }
            cur = !cur;
        }
    }
    return 0;
}

/* ------------------------------------------------------------------ the sweep reduced to Theorem 1 */

/* numpy's maximum folded left to right: a NaN sticks; of equal values the later one is kept
 * (np.maximum(a, b) returns b when a == b). Equal values are the same bits but for +0.0 and
 * -0.0: where both signs of zero are the largest deviation of a step, the sign of the result is
 * unspecified, in numpy (its reductions run in SIMD lanes) and here alike. */
static inline double later_max(double cur, double v)
{
    return (isnan(cur) || v < cur) ? cur : v;
}

/* The later_max fold of v[0..m-1] (or of -v, negated: -x is exact, the sign flipped as numpy's
 * negative) into cur: four running maxima, so the loop is not one chain of dependent comparisons,
 * combined in order; a NaN anywhere gives the first NaN. */
static double fold_max(double cur, const double *restrict v, int64_t m, int negate)
{
    double a0 = -INFINITY, a1 = -INFINITY, a2 = -INFINITY, a3 = -INFINITY;
    int64_t i = 0;
    int nan = 0;
    for (; i + 4 <= m; i += 4) {
        double x0 = negate ? -v[i] : v[i], x1 = negate ? -v[i + 1] : v[i + 1];
        double x2 = negate ? -v[i + 2] : v[i + 2], x3 = negate ? -v[i + 3] : v[i + 3];
        nan |= (x0 != x0) | (x1 != x1) | (x2 != x2) | (x3 != x3);
        a0 = x0 >= a0 ? x0 : a0;
        a1 = x1 >= a1 ? x1 : a1;
        a2 = x2 >= a2 ? x2 : a2;
        a3 = x3 >= a3 ? x3 : a3;
    }
    for (; i < m; ++i) {
        double x = negate ? -v[i] : v[i];
        nan |= x != x;
        a0 = x >= a0 ? x : a0;
    }
    if (nan) {
        for (i = 0; i < m; ++i) {
            double x = negate ? -v[i] : v[i];
            if (x != x)
                return later_max(cur, x);
        }
    }
    return later_max(later_max(later_max(later_max(cur, a0), a1), a2), a3);
}

/* One row N of a normal matrix applied to the deviations v[r][i], i < m, as plan_row (zeros
 * skipped, the first term assigned, the others added in order; an empty row gives 0.0) into out;
 * a row with one entry 1.0 gives v[r] itself (kernels.matvec_into copies it), returned without a
 * copy. Returns the values. */
static const double *normal_row(const double *N, int64_t ny, double *const *v, int64_t m, double *restrict out)
{
    int64_t nz = 0, last = 0;
    for (int64_t r = 0; r < ny; ++r)
        if (N[r] != 0.0) {
            ++nz;
            last = r;
        }
    if (nz == 1 && N[last] == 1.0)
        return v[last];
    int first = 1;
    for (int64_t r = 0; r < ny; ++r) {
        const double a = N[r];
        if (a == 0.0)
            continue;
        const double *restrict x = v[r];
        if (first)
            for (int64_t i = 0; i < m; ++i) out[i] = a * x[i];
        else
            for (int64_t i = 0; i < m; ++i) out[i] = out[i] + a * x[i];
        first = 0;
    }
    if (first)
        for (int64_t i = 0; i < m; ++i) out[i] = 0.0;
    return out;
}

/* The LWA-4P loop is also compiled for AVX2 (4 doubles per instruction) and picked at load time
 * on processors that have it (GCC's target_clones; no FMA: -ffp-contract=off keeps every product
 * rounded on its own, so the results are the same bits on either clone). */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
#define TARGET_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define TARGET_CLONES
#endif

/* Columns processed together: a chunk's partial sums (and in the LWA-4P loop its states) stay
 * in registers. */
#define LANES 8

/* acc[l] = row r of the plan applied to the columns v[.][c0 + l], l < LANES: plan_row's arithmetic
 * (first term assigned, the others added in order, an empty row 0.0) on one chunk, the running sum
 * kept in registers instead of stored and loaded again for every term. */
static inline void row_chunk(const plan_t *p, int64_t r, double *const *v, int64_t c0, double acc[LANES])
{
    int64_t a = p->start[r], b = p->start[r + 1];
    if (a == b) {
        for (int l = 0; l < LANES; ++l) acc[l] = 0.0;
        return;
    }
    const double k0 = p->coef[a];
    const double *v0 = v[p->col[a]] + c0;
    for (int l = 0; l < LANES; ++l) acc[l] = k0 * v0[l];
    for (int64_t e = a + 1; e < b; ++e) {
        const double ke = p->coef[e];
        const double *ve = v[p->col[e]] + c0;
        for (int l = 0; l < LANES; ++l) acc[l] = acc[l] + ke * ve[l];
    }
}

/* Whether row r of the plan has its nonzero entries exactly in the columns cols[0..len-1]. */
static int row_is(const plan_t *p, int64_t r, const int64_t *cols, int64_t len)
{
    if (p->start[r + 1] - p->start[r] != len)
        return 0;
    for (int64_t e = 0; e < len; ++e)
        if (p->col[p->start[r] + e] != cols[e])
            return 0;
    return 1;
}

/* Whether the plant has the sparsity of systems.plant.lwa4p_joint_plant (x = [q, qd, ..., u
 * delayed]; one output, one input, D = 0), for which lwa4p_extremes below holds the states
 * in registers. */
static int is_lwa4p(const plan_t *pA, const plan_t *pB, const plan_t *pC, int64_t n, int64_t nu, int64_t ny,
                    int64_t has_d)
{
    static const int64_t c0[] = {1}, c1[] = {1, 2, 3, 4}, c2[] = {2, 3, 4}, c3[] = {3}, z[] = {0};
    return n == 5 && nu == 1 && ny == 1 && !has_d && row_is(pA, 0, c0, 1) && row_is(pA, 1, c1, 4)
           && row_is(pA, 2, c2, 3) && row_is(pA, 3, c3, 1) && row_is(pA, 4, z, 0) && row_is(pB, 0, z, 0)
           && row_is(pB, 1, z, 0) && row_is(pB, 2, z, 0) && row_is(pB, 3, z, 0) && row_is(pB, 4, z, 1)
           && row_is(pC, 0, z, 1);
}

/* The test cases i < count (a multiple of LANES; X is n x M) of the LWA-4P plant (is_lwa4p), all
 * reaching step `horizon`, LANES at a time,
 * the chunk's states in registers from k = 0 to horizon: the operations of plan_row/row_chunk on
 * this sparsity in their order (x <- A x, then + B u, each product rounded on its own). Folds the
 * deviations y_a (the normal of every step is 1) into hi[k][l] and of -y_a into lo[k][l] per lane;
 * returns 1 if some y_a is NaN (the caller then runs the general loop, which keeps numpy's NaN). */
TARGET_CLONES static int lwa4p_extremes(const plan_t *pA, const plan_t *pB, const plan_t *pC, const double *y, const double *u,
                          const int64_t *starts, int64_t count, int64_t M, int64_t horizon, const double *X,
                          double (*hi)[LANES], double (*lo)[LANES])
{
    const double *cA = pA->coef;   /* entries in order: row 0: 1; row 1: 1 2 3 4; row 2: 2 3 4; row 3: 3 */
    const double a01 = cA[0], a11 = cA[1], a12 = cA[2], a13 = cA[3], a14 = cA[4];
    const double a22 = cA[5], a23 = cA[6], a24 = cA[7], a33 = cA[8], b40 = pB->coef[0], c00 = pC->coef[0];
    int nan = 0;
    for (int64_t i0 = 0; i0 + LANES <= count; i0 += LANES) {
        double x0[LANES], x1[LANES], x2[LANES], x3[LANES], x4[LANES];
        const int64_t *st = starts + i0;
        for (int l = 0; l < LANES; ++l) {
            x0[l] = X[0 * M + i0 + l];
            x1[l] = X[1 * M + i0 + l];
            x2[l] = X[2 * M + i0 + l];
            x3[l] = X[3 * M + i0 + l];
            x4[l] = X[4 * M + i0 + l];
        }
        int contiguous = 1;             /* consecutive start ticks (one segment): vector loads of y and u */
        for (int l = 1; l < LANES; ++l) contiguous &= st[l] == st[0] + l;
        for (int64_t k = 0; k <= horizon; ++k) {
            double *h = hi[k], *o = lo[k], yk[LANES], uk[LANES];
            if (contiguous) {
                for (int l = 0; l < LANES; ++l) {
                    yk[l] = y[st[0] + k + l];
                    uk[l] = u[st[0] + k + l];
                }
            } else {
                for (int l = 0; l < LANES; ++l) {
                    yk[l] = y[st[l] + k];
                    uk[l] = u[st[l] + k];
                }
            }
            for (int l = 0; l < LANES; ++l) {
                const double ya = yk[l] - c00 * x0[l];                    /* y - C x */
                const double na = -ya;
                nan |= ya != ya;
                h[l] = ya >= h[l] ? ya : h[l];
                o[l] = na >= o[l] ? na : o[l];
                const double n0 = a01 * x1[l];                            /* A x, row by row */
                const double n1 = a11 * x1[l] + a12 * x2[l] + a13 * x3[l] + a14 * x4[l];
                const double n2 = a22 * x2[l] + a23 * x3[l] + a24 * x4[l];
                const double n3 = a33 * x3[l];
                x0[l] = n0 + 0.0;                                         /* + B u (rows 0-3 empty: + 0.0) */
                x1[l] = n1 + 0.0;
                x2[l] = n2 + 0.0;
                x3[l] = n3 + 0.0;
                x4[l] = 0.0 + b40 * uk[l];                                /* row 4 of A is empty: 0.0 */
            }
        }
    }
    return nan;
}

/* The general loop of reachset_sweep_extremes over test cases i0 .. M-1 (see there). */
static int64_t general_extremes(const plan_t *pA, const plan_t *pB, const plan_t *pC, const plan_t *pD,
                                int64_t has_d, int64_t n, int64_t nu, int64_t ny, const double *y, const double *u,
                                const int64_t *starts, const int64_t *rem, int64_t i_first, int64_t M,
                                int64_t horizon, const double *X, const double *normals, const int64_t *qoff,
                                double *maxp, double *maxm)
{
    static __thread double xs[2][64][TILE], us[64][TILE], ys[64][TILE], yas[64][TILE], nys[TILE];
    double *xv[64], *xn[64], *uv[64], *yv[64];
    for (int64_t c = 0; c < nu; ++c) uv[c] = us[c];
    for (int64_t r = 0; r < ny; ++r) yv[r] = yas[r];
    for (int64_t i0 = i_first; i0 < M; i0 += TILE) {
        int64_t m = M - i0 < TILE ? M - i0 : TILE;
        int cur = 0;
        for (int64_t s = 0; s < n; ++s) memcpy(xs[cur][s], X + s * M + i0, (size_t)m * sizeof(double));
        for (int64_t k = 0; k <= horizon; ++k) {
            while (m > 0 && rem[i0 + m - 1] <= k) --m;      /* rem descending: drop ended test cases */
            if (m == 0)
                break;
            const int64_t *st = starts + i0;
            const int64_t mc = (m + LANES - 1) / LANES * LANES;     /* whole chunks; the rest is padding */
            for (int64_t s = 0; s < n; ++s) {
                xv[s] = xs[cur][s];
                xn[s] = xs[!cur][s];
            }
            for (int64_t c = 0; c < nu; ++c) {
                for (int64_t i = 0; i < m; ++i) us[c][i] = u[(st[i] + k) * nu + c];
                for (int64_t i = m; i < mc; ++i) us[c][i] = 0.0;
            }
            for (int64_t r = 0; r < ny; ++r) {
                for (int64_t i = 0; i < m; ++i) ys[r][i] = y[(st[i] + k) * ny + r];
                for (int64_t i = m; i < mc; ++i) ys[r][i] = 0.0;
            }
            for (int64_t c0 = 0; c0 < mc; c0 += LANES) {
                double acc[LANES], add[LANES];
                for (int64_t r = 0; r < ny; ++r) {               /* y_a = y - (C x (+ D u)) */
                    row_chunk(pC, r, xv, c0, acc);
                    if (has_d) {
                        row_chunk(pD, r, uv, c0, add);
                        for (int l = 0; l < LANES; ++l) acc[l] = acc[l] + add[l];
                    }
                    for (int l = 0; l < LANES; ++l) yas[r][c0 + l] = ys[r][c0 + l] - acc[l];
                }
                for (int64_t s = 0; s < n; ++s) {                /* x <- A x + B u */
                    row_chunk(pA, s, xv, c0, acc);
                    row_chunk(pB, s, uv, c0, add);
                    for (int l = 0; l < LANES; ++l) xn[s][c0 + l] = acc[l] + add[l];
                }
            }
            for (int64_t p = qoff[k]; p < qoff[k + 1]; ++p) {      /* the normals of N_k */
                const double *ny_p = normal_row(normals + p * ny, ny, yv, m, nys);
                maxp[p] = fold_max(maxp[p], ny_p, m, 0);
                maxm[p] = fold_max(maxm[p], ny_p, m, 1);
            }
            cur = !cur;
        }
    }
    return 0;
}

/* reachset_sweep_block fused with Theorem 1's reduction (theorem1.deviation_extremes): for every
 * step k <= horizon and normal p of N_k (rows qoff[k] .. qoff[k+1]-1 of `normals`, ny wide),
 *
 *     maxp[p] = the largest (N_k y_a)[p] over the test cases,  maxm[p] = the largest -(N_k y_a)[p],
 *
 * with y_a the deviations reachset_sweep_block computes (the same operations in the same order)
 * and N_k y_a kernels.matvec_into's (zeros skipped, first term assigned, the others added in
 * order); a NaN deviation gives NaN, as numpy's max. maxp and maxm come in filled with -inf. The
 * deviations of a tile stay in cache: nothing of size test cases x horizon is written. X (n x M,
 * the initial states) is read only. rem must be sorted in descending order. The LWA-4P plant
 * (is_lwa4p) with unit normals runs its test cases that reach step `horizon` in lwa4p_extremes.
 * Returns 0, or -1 if a size exceeds 64. */
int64_t reachset_sweep_extremes(const double *A, const double *B, const double *C, const double *D,
                                int64_t has_d, int64_t n, int64_t nu, int64_t ny,
                                const double *y, const double *u, const int64_t *starts, const int64_t *rem,
                                int64_t M, int64_t horizon, const double *X,
                                const double *normals, const int64_t *qoff, double *maxp, double *maxm)
{
    static __thread plan_t pA, pB, pC, pD;
    if (n > 64 || nu > 64 || ny > 64)
        return -1;
    make_plan(&pA, A, n, n);
    make_plan(&pB, B, n, nu);
    make_plan(&pC, C, ny, n);
    make_plan(&pD, D, ny, nu);
    int64_t fast = 0;                     /* test cases done by lwa4p_extremes: whole chunks reaching horizon */
    if (is_lwa4p(&pA, &pB, &pC, n, nu, ny, has_d) && qoff[horizon + 1] == horizon + 1) {
        int unit = 1;
        for (int64_t k = 0; k <= horizon; ++k) unit &= normals[k] == 1.0;
        while (unit && fast < M && rem[fast] > horizon) ++fast;
        fast -= fast % LANES;
        if (unit && fast > 0) {
            double (*hi)[LANES] = malloc((size_t)(horizon + 1) * sizeof *hi);
            double (*lo)[LANES] = malloc((size_t)(horizon + 1) * sizeof *lo);
            if (!hi || !lo) {
                free(hi);
                free(lo);
                return -1;
            }
            for (int64_t k = 0; k <= horizon; ++k)
                for (int l = 0; l < LANES; ++l) hi[k][l] = lo[k][l] = -INFINITY;
            int nan = lwa4p_extremes(&pA, &pB, &pC, y, u, starts, fast, M, horizon, X, hi, lo);
            for (int64_t k = 0; k <= horizon && !nan; ++k)
                for (int l = 0; l < LANES; ++l) {
                    maxp[k] = later_max(maxp[k], hi[k][l]);
                    maxm[k] = later_max(maxm[k], lo[k][l]);
                }
            free(hi);
            free(lo);
            if (nan)
                fast = 0;                 /* keep numpy's NaN: the general loop over all */
        } else {
            fast = 0;
        }
    }
    return general_extremes(&pA, &pB, &pC, &pD, has_d, n, nu, ny, y, u, starts, rem, fast, M, horizon, X, normals,
                            qoff, maxp, maxm);
}
