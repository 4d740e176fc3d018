/* One tick of the online conformance monitor (paper Theorem 1, checked tick by tick).
 *
 * A compiled copy of reachset_ros.conformance.monitor.Monitor._tick_numpy for the per-joint LWA-4P
 * plant with the "fd" initial-state estimator. Every floating-point operation is the one
 * numpy performs there, in the same order, each rounded on its own: this file must be
 * compiled with -ffp-contract=off (no fused multiply-add) and without -ffast-math, so
 * that the verdicts stay bitwise equal to `reachset check` (test/test_monitor_kernel.py
 * compares the two paths bit for bit).
 *
 * Loaded with ctypes by reachset_ros/conformance/kernels.py (with reachset_sweep_block below);
 * the state struct is mirrored by _TickState in reachset_ros/conformance/monitor.py. No
 * Python API is used.
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

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

/* The layout of tick_state above: kernels.TICK_ABI must equal it, or kernels.py does not use this
 * library (a stale build of an older layout would leave fields unwritten). 2: `use` added. */
int64_t reachset_tick_abi(void)
{
    return 2;
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
            /* the "fd" estimate, reachset_ros.conformance.estimators.fd_formula, same operation order */
            const double *yh = s->y_hist + j * W, *uh = s->u_hist + j * W;
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
