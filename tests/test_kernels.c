/* The compiled element kernels of solver/terms.c against the generic
 * evaluation (mrvi_element_eval): springs and anchors of every registered
 * law (the Hooke and small power forms inline, the others through the law
 * table), in dimensions 1, 2 and 3, on random configurations: the gradient
 * (mrvi_terms_grad and mrvi_terms_eval, scaled and unscaled) and the
 * Hessian, and so Hessian-vector products, to 1e-13 relative; the value
 * (mrvi_terms_value) likewise.  The kernels do mrvi_element_eval's
 * arithmetic in its order, so the check is also made bitwise.  A full
 * class of springs and anchors alone (no kterms) and one of Hooke springs
 * alone (no kspring records either, made in pieces) as well, with its
 * bytes (check_runs). */
#include "model/model.h"
#include "solver/solver.h"
#include "testlib.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

enum { N_PART = 7 };

/* Parameters of each registered law for a spring of rest length ~1 (the
 * power law with an integer exponent, inline, and one beyond 8, through
 * its table). */
typedef struct law_case {
  const char *law;
  double params[MRVI_LAW_MAX_PARAMS];
} law_case;

static const law_case cases[] = {
    {"linear", {2.5}},
    {"power", {1.25, 4}},
    {"power", {-0.3, 3}},
    {"power", {0.7, 2}},
    {"power", {0.05, 10}},
    {"morse", {0.8, 1.3}},
    {"lennard-jones", {0.6, 0.9, 3.0}},
    {"inverse", {0.4}},
};

static double uniform(unsigned long long *state) {
  *state = *state * 6364136223846793005ULL + 1442695040888963407ULL;
  return (double)(*state >> 11) / 4503599627370496.0 - 1.0;
}

/* A model of N_PART particles in dimension d joined by springs of law lc
 * (a chain and a few chords) and anchored by anchors of the same law, all
 * slow; NULL if the law is not registered. */
static mrvi_model *spring_model_rate(int d, const law_case *lc,
                                     unsigned long long *rng, int rate) {
  mrvi_model *m = mrvi_model_create();
  if (!m || mrvi_model_set_dimension(m, d) < 0) {
    mrvi_model_free(m);
    return NULL;
  }
  for (int i = 0; i < N_PART; i++) {
    double x[3] = {0, 0, 0}, v[3] = {0, 0, 0};
    x[0] = 1.1 * i;
    char name[16];
    snprintf(name, sizeof name, "p%d", i);
    CHECK(mrvi_model_add_particle(m, name, 1.0, rate, x, v) >= 0,
          "add particle: %s", mrvi_model_errmsg(m));
  }
  int ok = 1;
  for (int i = 0; i + 1 < N_PART; i++)
    ok = ok && mrvi_model_add_spring(m, rate, i, i + 1, lc->law, lc->params,
                                     1.0 + 0.1 * uniform(rng)) >= 0;
  for (int i = 0; i + 3 < N_PART; i += 2) /* chords */
    ok = ok && mrvi_model_add_spring(m, rate, i + 3, i, lc->law, lc->params,
                                     2.9) >= 0;
  for (int i = 0; i < N_PART; i += 3) { /* anchors, then a spring again */
    const double a[3] = {1.1 * i + 0.3, 0.5, -0.2};
    ok = ok && mrvi_model_add_anchor_spring(m, rate, i, a, lc->law, lc->params,
                                            0.6) >= 0;
  }
  ok = ok && mrvi_model_add_spring(m, rate, 1, N_PART - 1, lc->law, lc->params,
                                   5.0) >= 0;
  CHECK(ok, "%s: springs: %s", lc->law, mrvi_model_errmsg(m));
  return m;
}

static mrvi_model *spring_model(int d, const law_case *lc,
                                unsigned long long *rng) {
  return spring_model_rate(d, lc, rng, MRVI_SLOW);
}

/* Relative difference of x and y (n entries) in the max norm. */
/* k rounded up to an even count (the threaded classes' parts). */
static int even_count(int k) { return k + (k & 1); }

static double rel_diff(const double *x, const double *y, size_t n) {
  double e = 0.0, s = 0.0;
  for (size_t i = 0; i < n; i++) {
    e = fmax(e, fabs(x[i] - y[i]));
    s = fmax(s, fabs(y[i]));
  }
  return s > 0.0 ? e / s : e;
}

static void check_case(int d, const law_case *lc, unsigned long long *rng) {
  mrvi_model *m = spring_model(d, lc, rng);
  if (!m)
    return;
  const int n = m->n, ne = m->n_elements;
  const size_t nn = (size_t)n * (size_t)n;
  int *elems = calloc((size_t)ne, sizeof *elems);
  double *q = calloc((size_t)n, sizeof *q), *g = calloc((size_t)n, sizeof *g);
  double *gr = calloc((size_t)n, sizeof *gr),
         *gs = calloc((size_t)n, sizeof *gs);
  double *gs_ref = calloc((size_t)n, sizeof *gs_ref);
  double *H = calloc(nn, sizeof *H), *Hr = calloc(nn, sizeof *Hr);
  double *Hs = calloc(nn, sizeof *Hs), *Hs_ref = calloc(nn, sizeof *Hs_ref);
  double *v = calloc((size_t)n, sizeof *v), *Hv = calloc((size_t)n, sizeof *Hv);
  double *Hv_ref = calloc((size_t)n, sizeof *Hv_ref);
  for (int e = 0; e < ne; e++)
    elems[e] = e;
  mrvi_terms *kc = NULL;
  CHECK(mrvi_terms_create(m, elems, ne, NULL, &kc) == MRVI_OK,
        "d %d %s: create", d, lc->law);
  for (int r = 0; kc && r < 6; r++) {
    for (int i = 0; i < n; i++) {
      q[i] = m->q0[i] + 0.3 * uniform(rng);
      v[i] = uniform(rng);
      g[i] = gr[i] = gs[i] = gs_ref[i] = Hv[i] = Hv_ref[i] = 0.0;
    }
    memset(H, 0, nn * sizeof *H);
    memset(Hs, 0, nn * sizeof *Hs);
    memset(Hs_ref, 0, nn * sizeof *Hs_ref);
    memset(Hr, 0, nn * sizeof *Hr);
    /* The reference: the generic element evaluation, scattered. */
    const double val_ref = mrvi_model_potential(m, MRVI_SLOW, q, gr, Hr);
    const double scale = 0.37, hscale = -1.9;
    for (int e = 0; e < ne; e++) {
      const mrvi_element *el = MRVI_ELEMENT(m, e);
      double y[6], ge[6], He[36];
      for (int j = 0; j < el->n_in; j++)
        y[j] = q[el->in[j]];
      mrvi_element_eval(m, el, y, ge, He);
      for (int j = 0; j < el->n_in; j++) {
        gs_ref[el->in[j]] += scale * ge[j];
        for (int l = 0; l < el->n_in; l++)
          Hs_ref[(size_t)el->in[j] * (size_t)n + (size_t)el->in[l]] +=
              hscale * He[j * el->n_in + l];
      }
    }
    mrvi_terms_grad(kc, q, g);
    mrvi_terms_eval(kc, q, 1.0, gs, H, n, 1.0);
    double e_g = rel_diff(g, gr, (size_t)n), e_H = rel_diff(H, Hr, nn);
    CHECK(e_g <= 1e-13, "d %d %s (%g): gradient %.2e relative", d, lc->law,
          lc->params[1], e_g);
    CHECK(e_H <= 1e-13, "d %d %s (%g): Hessian %.2e relative", d, lc->law,
          lc->params[1], e_H);
    CHECK(memcmp(g, gr, (size_t)n * sizeof *g) == 0 &&
              memcmp(gs, gr, (size_t)n * sizeof *g) == 0 &&
              memcmp(H, Hr, nn * sizeof *H) == 0,
          "d %d %s (%g): bitwise the generic gradient and Hessian", d, lc->law,
          lc->params[1]);
    /* Hessian-vector products. */
    for (int i = 0; i < n; i++)
      for (int j = 0; j < n; j++) {
        Hv[i] += H[(size_t)i * (size_t)n + (size_t)j] * v[j];
        Hv_ref[i] += Hr[(size_t)i * (size_t)n + (size_t)j] * v[j];
      }
    const double e_Hv = rel_diff(Hv, Hv_ref, (size_t)n);
    CHECK(e_Hv <= 1e-13, "d %d %s (%g): Hessian-vector %.2e relative", d,
          lc->law, lc->params[1], e_Hv);
    /* Scaled gradient and Hessian (the implicit paths' weights). */
    memset(gs, 0, (size_t)n * sizeof *gs);
    mrvi_terms_eval(kc, q, scale, gs, Hs, n, hscale);
    const double e_gs = rel_diff(gs, gs_ref, (size_t)n),
                 e_Hs = rel_diff(Hs, Hs_ref, nn);
    CHECK(e_gs <= 1e-13 && e_Hs <= 1e-13,
          "d %d %s (%g): scaled gradient %.2e, Hessian %.2e relative", d,
          lc->law, lc->params[1], e_gs, e_Hs);
    /* The gradient on threads, in parts of about 2 columns (a particle
     * split in 2-D and 3-D) and of about 2 records (ncol = 0), an even
     * number of them: the serial one bitwise for 2 and 3 threads. */
    for (int t = 2; t <= 3; t++)
      for (int by_rec = 0; by_rec <= 1; by_rec++) {
        mrvi_terms *kt = NULL;
        CHECK(mrvi_terms_create(m, elems, ne, NULL, &kt) == MRVI_OK &&
                  mrvi_terms_set_threads(kt, t, 2, by_rec ? 0 : n) == MRVI_OK,
              "d %d %s: threaded create", d, lc->law);
        if (!kt)
          continue;
        CHECK(mrvi_terms_threads(kt) == (mrvi_threads_supported() ? t : 1) &&
                  mrvi_terms_parts(kt) ==
                      (mrvi_threads_supported()
                           ? even_count(by_rec ? (ne + 1) / 2 : (n + 1) / 2)
                           : 0),
              "d %d %s: %d threads in use, %d asked, %d parts", d, lc->law,
              mrvi_terms_threads(kt), t, mrvi_terms_parts(kt));
        memset(gs, 0, (size_t)n * sizeof *gs);
        mrvi_terms_grad(kt, q, gs);
        CHECK(memcmp(gs, g, (size_t)n * sizeof *g) == 0,
              "d %d %s (%g): %d threads, parts by %s: the serial gradient "
              "bitwise",
              d, lc->law, lc->params[1], t, by_rec ? "records" : "columns");
        mrvi_terms_free(kt);
      }
    /* ... and in parts doubled while records span them (the explicit
     * path's, mrvi_terms_set_threads_spread): with no spread allowed,
     * fewer parts (at least two) where records span the parts of 2 and
     * a doubling leaves two (8 columns or records), none doubled with any
     * allowed; the serial gradient bitwise (the parts in turn). */
    for (int any = 0; any <= 1 && mrvi_threads_supported(); any++)
      for (int by_rec = 0; by_rec <= 1; by_rec++) {
        mrvi_terms *kt = NULL;
        CHECK(mrvi_terms_create(m, elems, ne, NULL, &kt) == MRVI_OK &&
                  mrvi_terms_set_threads_spread(kt, 2, 2, by_rec ? 0 : n,
                                                any ? HUGE_VAL : 0.0) ==
                      MRVI_OK,
              "d %d %s: spread create", d, lc->law);
        if (!kt)
          continue;
        const int plain = even_count(by_rec ? (ne + 1) / 2 : (n + 1) / 2);
        const int np = mrvi_terms_parts(kt), cnt = by_rec ? ne : n;
        CHECK(any || cnt < 8 ? np == plain : np >= 2 && np < plain,
              "d %d %s: %d parts with %s spread, %d without", d, lc->law, np,
              any ? "any" : "no", plain);
        memset(gs, 0, (size_t)n * sizeof *gs);
        for (int c = 0; c < np; c++) /* (each part its own columns) */
          mrvi_terms_grad_part(kt, c, q, gs);
        CHECK(memcmp(gs, g, (size_t)n * sizeof *g) == 0,
              "d %d %s (%g): parts by %s, spread %s: the serial gradient "
              "bitwise",
              d, lc->law, lc->params[1], by_rec ? "records" : "columns",
              any ? "any" : "none");
        mrvi_terms_free(kt);
      }
    const double val = mrvi_terms_value(kc, q);
    CHECK(fabs(val - val_ref) <= 1e-13 * fabs(val_ref),
          "d %d %s: value %.17g vs %.17g", d, lc->law, val, val_ref);
    /* The values-only class (the run's energies): the full class's value
     * bitwise, on the whole class (anchors in it: the full records) and on
     * its springs alone (for the linear law, khooke records alone). */
    for (int only = 0; only < 2 && r == 0; only++) {
      int ns = 0, *sel = calloc((size_t)ne, sizeof *sel);
      for (int i = 0; sel && i < ne; i++)
        if (!only || m->erecs[i].kind == MRVI_ELEMENT_SPRING)
          sel[ns++] = i;
      mrvi_terms *kf = NULL, *kv = NULL;
      CHECK(sel && mrvi_terms_create(m, sel, ns, NULL, &kf) == MRVI_OK &&
                mrvi_terms_create_value(m, sel, ns, &kv) == MRVI_OK,
            "d %d %s: values-only create", d, lc->law);
      if (kf && kv) {
        const double vf = mrvi_terms_value(kf, q), vv = mrvi_terms_value(kv, q);
        CHECK(memcmp(&vf, &vv, sizeof vf) == 0,
              "d %d %s (%d springs): values-only %.17g vs %.17g", d, lc->law,
              ns, vv, vf);
        /* and in chunks of 4 elements (the run's energies on threads) */
        CHECK(mrvi_terms_set_value_chunks(kf, 2, 4) == MRVI_OK &&
                  mrvi_terms_set_value_chunks(kv, 2, 4) == MRVI_OK,
              "d %d %s: value chunks", d, lc->law);
        const double cf = mrvi_terms_value(kf, q), cv = mrvi_terms_value(kv, q);
        CHECK(memcmp(&cf, &cv, sizeof cf) == 0,
              "d %d %s (%d springs): values-only in chunks %.17g vs %.17g", d,
              lc->law, ns, cv, cf);
      }
      mrvi_terms_free(kf);
      mrvi_terms_free(kv);
      free(sel);
    }
    /* The gradient-only class (mrvi_terms_create_grad) of the springs
     * alone and of the anchors alone, each of one kind and one law: their
     * records alone (solver/terms.c, spring_class; linear springs:
     * hooke_class, whose one division per spring may differ in the last
     * bit, to 1e-13, and on 2 threads the serial class's bitwise): the
     * full class's gradient and value bitwise, serially and on 2 threads
     * in parts of 2 records; kind 2, the chords alone (one
     * stiffness and rest length: hooke_class's columns alone). */
    static const char *const names[] = {"springs", "anchors", "chords"};
    for (int kind = 0; kind < 3 && r == 0; kind++) {
      const int want = kind == 1 ? MRVI_ELEMENT_ANCHOR : MRVI_ELEMENT_SPRING;
      int ns = 0, *sel = calloc((size_t)ne, sizeof *sel);
      for (int i = 0; sel && i < ne; i++)
        if (m->erecs[i].kind == want &&
            (kind < 2 || MRVI_ELEMENT(m, i)->shift == 2.9))
          sel[ns++] = i;
      mrvi_terms *kf = NULL, *kg = NULL, *kt = NULL;
      CHECK(sel && mrvi_terms_create(m, sel, ns, NULL, &kf) == MRVI_OK &&
                mrvi_terms_create_grad(m, sel, ns, NULL, &kg) == MRVI_OK &&
                mrvi_terms_create_grad(m, sel, ns, NULL, &kt) == MRVI_OK &&
                mrvi_terms_set_threads(kt, 2, 2, 0) == MRVI_OK,
            "d %d %s: gradient-only create", d, lc->law);
      if (kf && kg && kt) {
        memset(gs_ref, 0, (size_t)n * sizeof *gs_ref);
        memset(gs, 0, (size_t)n * sizeof *gs);
        memset(Hv, 0, (size_t)n * sizeof *Hv);
        mrvi_terms_grad(kf, q, gs_ref);
        mrvi_terms_grad(kg, q, gs);
        mrvi_terms_grad(kt, q, Hv);
        const size_t bytes = (size_t)n * sizeof *gs;
        const int exact = kind == 1 || strcmp(lc->law, "linear") != 0;
        CHECK(exact ? !memcmp(gs, gs_ref, bytes) && !memcmp(Hv, gs_ref, bytes)
                    : rel_diff(gs, gs_ref, (size_t)n) <= 1e-13 &&
                          !memcmp(Hv, gs, bytes),
              "d %d %s (%g), %s alone: gradient-only class %.2e relative to "
              "the full class's, on 2 threads %.2e (bitwise the serial "
              "class's: its springs two a lane pair, hooke_grad1, against "
              "the parts' one at a time)",
              d, lc->law, lc->params[1], names[kind],
              rel_diff(gs, gs_ref, (size_t)n), rel_diff(Hv, gs, (size_t)n));
        /* ... and in larger parts (chunks of 3 and 6 records or 2 and 3
         * columns): runs of whole consecutive records, which the parts
         * take by the serial pair loop (part_hooke_pairs), between masked
         * records and odd tails, each part in turn: the serial gradient
         * bitwise */
        for (int big = 0; big < 4 && mrvi_threads_supported(); big++) {
          const int by_rec = big < 2,
                    chunk = by_rec ? 3 + 3 * big : 2 + big % 2;
          mrvi_terms *kb = NULL;
          CHECK(mrvi_terms_create_grad(m, sel, ns, NULL, &kb) == MRVI_OK &&
                    mrvi_terms_set_threads(kb, 2, chunk, by_rec ? 0 : n) ==
                        MRVI_OK,
                "d %d %s: gradient-only create in parts of %d", d, lc->law,
                chunk);
          const int np = kb ? mrvi_terms_parts(kb) : 0;
          memset(Hv, 0, (size_t)n * sizeof *Hv);
          for (int c = 0; c < np; c++)
            mrvi_terms_grad_part(kb, c, q, Hv);
          CHECK((by_rec ? ns : n) < 2 * chunk ||
                    (np >= 2 && !memcmp(Hv, gs, bytes)),
                "d %d %s (%g), %s alone, %d parts of %d %s: the serial "
                "gradient-only class's bitwise (%.2e relative)",
                d, lc->law, lc->params[1], names[kind], np, chunk,
                by_rec ? "records" : "columns", rel_diff(Hv, gs, (size_t)n));
          mrvi_terms_free(kb);
        }
        const double vf = mrvi_terms_value(kf, q), vg = mrvi_terms_value(kg, q);
        CHECK(memcmp(&vf, &vg, sizeof vf) == 0,
              "d %d %s, %s alone: gradient-only class's value %.17g vs %.17g",
              d, lc->law, names[kind], vg, vf);
        /* springs of one compiled law other than Hooke's (one parameter
         * set here): the law once, columns and rest lengths per spring
         * (spring_class's kspair records); scaled, with the Hessian, as
         * the full class bitwise */
        const int code = !strcmp(lc->law, "morse") ||
                         (!strcmp(lc->law, "power") && lc->params[1] <= 8);
        CHECK(mrvi_terms_shared_law(kg) == (kind != 1 && code),
              "d %d %s (%g), %s alone: one law kept once: %d", d, lc->law,
              lc->params[1], names[kind], mrvi_terms_shared_law(kg));
        memset(gs_ref, 0, (size_t)n * sizeof *gs_ref);
        memset(gs, 0, (size_t)n * sizeof *gs);
        memset(Hs_ref, 0, (size_t)n * n * sizeof *Hs_ref);
        memset(Hs, 0, (size_t)n * n * sizeof *Hs);
        const int shared = kind != 1 && code;
        mrvi_terms_eval(kf, q, 0.5, gs_ref, Hs_ref, n, 0.25);
        if (shared)
          mrvi_terms_eval(kg, q, 0.5, gs, Hs, n, 0.25);
        CHECK(!shared || (!memcmp(gs, gs_ref, bytes) &&
                          !memcmp(Hs, Hs_ref, (size_t)n * n * sizeof *Hs)),
              "d %d %s (%g), %s alone: the gradient-only class scaled, "
              "with the Hessian, as the full class's",
              d, lc->law, lc->params[1], names[kind]);
      }
      mrvi_terms_free(kf);
      mrvi_terms_free(kg);
      mrvi_terms_free(kt);
      free(sel);
    }
  }
  mrvi_terms_free(kc);
  free(elems);
  free(q);
  free(g);
  free(gr);
  free(gs);
  free(gs_ref);
  free(H);
  free(Hr);
  free(Hs);
  free(Hs_ref);
  free(v);
  free(Hv);
  free(Hv_ref);
  mrvi_model_free(m);
}

/* The sparse-block kernel (mrvi_sblock_add_terms: springs and anchors
 * compiled, the sweep-cg path's micro-step matrix) against the generic
 * evaluation scattered by mrvi_sblock_add_element, bitwise, and its
 * Hessian-vector products against central differences of the gradient. */
/* sweep-cg's chord pass fused into the spring loop: mrvi_terms_grad_fused
 * on a class of Hooke springs alone after mrvi_terms_set_recip, in blocks
 * of 1, 3 and 64 records, g filled with NaN before (every column zeroed
 * by the kernel): mrvi_terms_grad's gradient bitwise; the callback's
 * columns increase to n, and the columns it reports complete are final
 * (their g then equals the end's bitwise) and no longer read (z there
 * overwritten with NaN by the callback); with the first callback (the
 * next row's end formed in the loop), z NaN until first reports its
 * column, which g must not yet have been written in.  Other classes keep
 * none. */
typedef struct fuse_seen {
  double *g;
  const double *q;
  double *z, *gc;
  int last, calls, ok, first;
} fuse_seen;

/* mrvi_terms_grad_fused's first: the columns it reports still unread and
 * unsummed (g there still NaN), their z set only now (NaN before, so that
 * a record reading one earlier poisons the gradient) and g zeroed (first's
 * task: the kernel leaves them). */
static void fuse_first(void *ctx, int c) {
  fuse_seen *s = ctx;
  s->ok &= c > s->first;
  for (int f = s->first; f < c; f++) {
    s->ok &= isnan(s->g[f]) != 0;
    s->z[f] = s->q[f];
    s->g[f] = 0.0;
  }
  s->first = c;
}

static void fuse_cols(void *ctx, int c) {
  fuse_seen *s = ctx;
  s->ok &= c > s->last;
  for (int f = s->last; f < c; f++) {
    s->gc[f] = s->g[f];
    s->z[f] = NAN;
  }
  s->last = c;
  s->calls++;
}

static void check_fused(const mrvi_model *m, const int *sel, int nsp,
                        const double *q, int n, int d, const law_case *lc) {
  mrvi_terms *kf = NULL;
  CHECK(mrvi_terms_create(m, sel, nsp, m->slot, &kf) == MRVI_OK,
        "d %d %s: create", d, lc->law);
  double *w = calloc(4 * (size_t)n, sizeof *w);
  if (!kf || !w) {
    CHECK(0, "d %d: memory", d);
    mrvi_terms_free(kf);
    free(w);
    return;
  }
  const int hooke = mrvi_terms_set_recip(kf);
  double *g0 = w, *g1 = w + n, *gc = w + 2 * n, *z = w + 3 * n;
  mrvi_terms_grad(kf, q, g0);
  const int blocks[3] = {1, 3, 64};
  for (int b = 0; b < 6; b++) {
    const int set = mrvi_terms_set_fused(kf, n, blocks[b % 3]);
    CHECK(set == (hooke && nsp > 0) && mrvi_terms_fused(kf) == set,
          "d %d %s: fused %d (Hooke springs alone: %d)", d, lc->law, set,
          hooke);
    if (set != 1)
      continue;
    const int first = b >= 3; /* (with first: z set there) */
    for (int i = 0; i < n; i++) {
      g1[i] = gc[i] = NAN;
      z[i] = first ? NAN : q[i];
    }
    fuse_seen s = {g1, q, z, gc, 0, 0, 1, 0};
    mrvi_terms_grad_fused(kf, z, g1, first ? fuse_first : NULL, fuse_cols, &s);
    CHECK(s.ok && s.last == n && s.first == (first ? n : 0) &&
              !memcmp(g0, g1, (size_t)n * sizeof *g0) &&
              !memcmp(g1, gc, (size_t)n * sizeof *g1),
          "d %d block %d first %d: %d calls to column %d; the fused gradient "
          "bitwise mrvi_terms_grad's, the complete columns final and unread, "
          "first's columns before any read",
          d, blocks[b % 3], first, s.calls, s.last);
  }
  mrvi_terms_free(kf);
  free(w);
}

/* sweep-cg's row 0 bound (mrvi_terms_gershgorin) on a class of springs
 * and anchors: at least the Gershgorin bound of the assembled matrix
 * hscale hess Z (mrvi_terms_eval's dense Hessian, rows scaled by a
 * positive dinv) and at most the elements' bound from
 * mrvi_terms_grad_hdiag's off (to 1e-13 relative): a bound that dropped
 * or mis-slotted a particle's own off-diagonal sums would fall below the
 * assembled one.  Where kt is in np >= 2 parts by columns, the parts
 * (mrvi_terms_gershgorin_part, sweep-cg's row 0 on threads), taken in
 * reverse over arrays of NaN, give the same s, o and bound bitwise. */
static void check_gersh(mrvi_terms *kt, const double *q, int n, int d,
                        const law_case *lc, int np, unsigned long long *rng) {
  if (!mrvi_terms_springs_only(kt))
    return;
  const double hs = 0.25 * (1.0 + uniform(rng));
  double *H = calloc((size_t)n * (size_t)n, sizeof *H);
  double *w = calloc(5 * (size_t)n, sizeof *w);
  if (!H || !w) {
    CHECK(0, "d %d: memory", d);
    free(H);
    free(w);
    return;
  }
  double *g = w, *dinv = w + n, *s = w + 2 * n, *o = w + 3 * n, *hd = w + 4 * n;
  mrvi_terms_eval(kt, q, 1.0, g, H, n, hs);
  double ref = 0.0;
  for (int i = 0; i < n; i++) {
    dinv[i] = 1.0 / (fabs(H[(size_t)i * n + i]) + 1.0 + uniform(rng));
    double t = 0.0;
    for (int j = 0; j < n; j++)
      t += j != i ? fabs(H[(size_t)i * n + j]) : 0.0;
    ref = fmax(ref, t * dinv[i]);
  }
  const double b = mrvi_terms_gershgorin(kt, q, hs, dinv, s, o, n);
  double *w2 = np >= 2 ? malloc(2 * (size_t)n * sizeof *w2) : NULL;
  if (w2) {
    for (int i = 0; i < 2 * n; i++)
      w2[i] = NAN;
    for (int c = np - 1; c >= 0; c--)
      mrvi_terms_gershgorin_part(kt, c, q, hs, dinv, w2, w2 + n, 0);
    double bp = 0.0;
    for (int c = np - 1; c >= 0; c--) {
      const double v =
          mrvi_terms_gershgorin_part(kt, c, q, hs, dinv, w2, w2 + n, 1);
      bp = v > bp || isnan(v) ? v : bp;
    }
    bp = isfinite(bp) ? bp : HUGE_VAL;
    CHECK(!memcmp(&bp, &b, sizeof b) && !memcmp(w2, s, (size_t)n * sizeof *s) &&
              !memcmp(w2 + n, o, (size_t)n * sizeof *o),
          "d %d %s: row 0 bound in %d parts by columns %.17g, serial %.17g, "
          "the sums bitwise",
          d, lc->law, np, bp, b);
    free(w2);
  }
  memset(g, 0, (size_t)n * sizeof *g);
  memset(hd, 0, (size_t)n * sizeof *hd);
  memset(o, 0, (size_t)n * sizeof *o);
  mrvi_terms_grad_hdiag(kt, q, g, hd, o, hs);
  double elem = 0.0;
  for (int i = 0; i < n; i++)
    elem = fmax(elem, o[i] * dinv[i]);
  CHECK(b >= ref * (1.0 - 1e-13) && b <= elem * (1.0 + 1e-13),
        "d %d %s: row 0 bound %.17g, assembled %.17g, elements' %.17g", d,
        lc->law, b, ref, elem);
  free(H);
  free(w);
}

/* sweep-cg's linearised chord updates (tuning.chord_linear) on a class of
 * Hooke springs alone after mrvi_terms_set_recip, partitioned in np parts:
 * mrvi_terms_grad_lin's gradient bitwise mrvi_terms_grad's; the Hessian
 * products from its records against mrvi_terms_hessvec's (the generic
 * derivatives) to 1e-13 relative and against central differences of the
 * gradient; the parts in reverse order give the serial gradient, records
 * and products bitwise.  Other classes (other laws, anchors) keep none. */
static void check_lin(mrvi_terms *kt, const double *q, int n, int np, int d,
                      const law_case *lc, int hooke, unsigned long long *rng) {
  const long nl = mrvi_terms_lin_size(kt);
  CHECK(hooke == (strcmp(lc->law, "linear") == 0 && nl > 0) &&
            (hooke || nl == 0),
        "d %d %s: %ld linearisation doubles (Hooke springs alone: %d)", d,
        lc->law, nl, hooke);
  if (nl <= 0)
    return;
  double *w = calloc(8 * (size_t)n, sizeof *w);
  double *l1 = calloc(2 * (size_t)nl, sizeof *l1), *l2 = l1 + nl;
  if (!w || !l1) {
    CHECK(0, "d %d: memory", d);
    free(w);
    free(l1);
    return;
  }
  double *g0 = w, *g1 = w + n, *g2 = w + 2 * n, *x = w + 3 * n;
  double *h1 = w + 4 * n, *h2 = w + 5 * n, *h3 = w + 6 * n, *qq = w + 7 * n;
  mrvi_terms_grad(kt, q, g0);
  mrvi_terms_grad_lin(kt, q, g1, l1);
  for (int c = np - 1; c >= 0; c--)
    mrvi_terms_grad_lin_part(kt, c, q, g2, l2);
  CHECK(!memcmp(g0, g1, (size_t)n * sizeof *g0) &&
            !memcmp(g1, g2, (size_t)n * sizeof *g1) &&
            !memcmp(l1, l2, (size_t)nl * sizeof *l1),
        "d %d: the linearisation's gradient bitwise mrvi_terms_grad's, its "
        "parts' gradient and records bitwise the serial ones",
        d);
  for (int i = 0; i < n; i++)
    x[i] = uniform(rng);
  const double s = 0.37;
  mrvi_terms_hv_lin(kt, q, l1, x, s, h1);
  for (int c = np - 1; c >= 0; c--)
    mrvi_terms_hv_lin_part(kt, c, q, l1, x, s, h2);
  mrvi_terms_hessvec(kt, q, 1, x, 0, h3, 0, s);
  double e = 0.0, sc = 0.0;
  for (int i = 0; i < n; i++) {
    e = fmax(e, fabs(h1[i] - h3[i]));
    sc = fmax(sc, fabs(h3[i]));
  }
  CHECK(!memcmp(h1, h2, (size_t)n * sizeof *h1),
        "d %d: the products in parts bitwise the serial one", d);
  CHECK(sc > 0.0 && e <= 1e-13 * sc,
        "d %d: Hessian product from the records %.2e against "
        "mrvi_terms_hessvec's (scale %.2e)",
        d, e, sc);
  /* ... and against central differences of the gradient along x */
  const double h = 1e-6;
  for (int i = 0; i < n; i++) {
    qq[i] = q[i] + h * x[i];
    g1[i] = g2[i] = 0.0;
  }
  mrvi_terms_grad(kt, qq, g1);
  for (int i = 0; i < n; i++)
    qq[i] = q[i] - h * x[i];
  mrvi_terms_grad(kt, qq, g2);
  double ef = 0.0;
  for (int i = 0; i < n; i++)
    ef = fmax(ef, fabs(h1[i] - s * (g1[i] - g2[i]) / (2 * h)));
  CHECK(ef <= 1e-6 * sc,
        "d %d: Hessian product %.2e against central "
        "differences (scale %.2e)",
        d, ef, sc);
  free(w);
  free(l1);
}

/* The block's CG on the parts (mrvi_sblock_solve, one parallel region):
 * J = the values at q + dscale I, assembled again before each solve, with
 * the smallest dscale of |hscale| 2^j for which CG finds no direction of
 * non-positive curvature (no fallback to LU); on 1, 2 and 3 threads: the
 * same bits, and J x = b to the CG's tolerance (J x by the block's
 * product, against the right-hand side). */
static void check_sparse_solve(mrvi_sblock *sp, const mrvi_terms *kt, int n,
                               int np, const double *q, double *gp,
                               double hscale, unsigned long long *rng) {
  double *w = calloc(5 * (size_t)n, sizeof *w);
  CHECK(w != NULL, "solve: out of memory");
  if (!w)
    return;
  double *b = w, *one = w + n, *x1 = w + 2 * n, *rhs = w + 3 * n,
         *y = w + 4 * n;
  for (int i = 0; i < n; i++) {
    rhs[i] = uniform(rng);
    one[i] = 1.0;
  }
  char msg[256] = "";
  int st = MRVI_OK, same = 1, t = 1;
  long its = 0, fb = 0;
  double dscale = fabs(hscale);
  for (int j = 0; j < 200 && t <= 3 && st == MRVI_OK; j += t == 1) {
    mrvi_sblock_set_parts(sp, np, t);
    for (int c = 0; c < np; c++)
      mrvi_sblock_add_terms_part(sp, kt, c, q, gp, hscale, 1);
    memcpy(b, rhs, (size_t)n * sizeof *b);
    const mrvi_krylov_stats *ks = mrvi_sblock_stats(sp);
    const long i0 = ks->cg_iterations, f0 = ks->fallbacks;
    st = mrvi_sblock_solve(sp, one, 1, dscale, b, 1e-14, msg, sizeof msg);
    its = ks->cg_iterations - i0;
    fb = ks->fallbacks - f0;
    if (t == 1 && fb) { /* (not positive definite: a larger shift) */
      dscale *= 2.0;
      continue;
    }
    if (t == 1)
      memcpy(x1, b, (size_t)n * sizeof *b);
    else
      same = same && !memcmp(x1, b, (size_t)n * sizeof *b);
    t++;
  }
  mrvi_sblock_matvec(sp, x1, y);
  double e = 0.0, sc = 0.0;
  for (int i = 0; i < n; i++) {
    e = fmax(e, fabs(y[i] - rhs[i]));
    sc = fmax(sc, fabs(rhs[i]));
  }
  CHECK(st == MRVI_OK && t == 4 && fb == 0 && same && its >= 2 &&
            e <= 1e-10 * sc,
        "%d parts: the CG on the parts (J + %g I) the same bits on 1, 2, 3 "
        "threads (%d), %ld iterations, J x - b %.2e (scale %.2e) %s",
        np, dscale, same, its, e, sc, msg);
  free(w);
}

/* The sparse block on threads (mrvi_sblock_set_parts, sweep-cg's Newton
 * matrix): the class kt partitioned by columns in np parts, taken in
 * reverse, each zeroing its columns first (the values start as garbage):
 * the values and gradient of mrvi_sblock_add_terms (sb at q, g) bitwise;
 * the Jacobi bound and D^-1 the serial ones bitwise; the product in row
 * form the same bits on 1, 2 and 3 threads and the serial scatter's to
 * 1e-14 relative. */
static void check_sparse_parts(const mrvi_model *m, const int *elems,
                               mrvi_terms *kt, int np, const double *q,
                               const double *g, const mrvi_sblock *sb,
                               double hscale, unsigned long long *rng) {
  const int n = m->n, d = m->dimension;
  mrvi_sblock *sp = NULL;
  double *w = calloc(7 * (size_t)n, sizeof *w);
  CHECK(w && mrvi_terms_sparse_parts(kt) == np &&
            mrvi_sblock_create(m, elems, m->n_elements, 512, &sp) == MRVI_OK &&
            mrvi_sblock_set_parts(sp, np, 2) == MRVI_OK &&
            mrvi_sblock_parts(sp) == np,
        "d %d: the block in %d parts", d, np);
  if (!w || !sp || mrvi_sblock_parts(sp) != np) {
    free(w);
    mrvi_sblock_free(sp);
    return;
  }
  double *gp = w, *x = w + n, *y1 = w + 2 * n, *y2 = w + 3 * n;
  double *ys = w + 4 * n, *d1 = w + 5 * n, *d2 = w + 6 * n;
  for (int i = 0; i < n; i++)
    x[i] = q[i] + 0.5 * uniform(rng);
  mrvi_sblock_add_terms(sp, kt, x, y1, 3.0); /* (garbage values) */
  for (int c = np - 1; c >= 0; c--)
    mrvi_sblock_add_terms_part(sp, kt, c, q, gp, hscale, 1);
  long nnz = 0, nnz_p = 0;
  const double *Ax = mrvi_sblock_values(sb, &nnz);
  const double *Ap = mrvi_sblock_values(sp, &nnz_p);
  CHECK(nnz == nnz_p && memcmp(Ax, Ap, (size_t)nnz * sizeof *Ax) == 0 &&
            memcmp(g, gp, (size_t)n * sizeof *g) == 0,
        "d %d: %d parts: the values and gradient bitwise the serial ones", d,
        np);
  const double b1 = mrvi_sblock_jacobi(sb, d1);
  const double b2 = mrvi_sblock_jacobi(sp, d2);
  CHECK(b1 == b2 && (b1 == HUGE_VAL || !memcmp(d1, d2, (size_t)n * sizeof *d1)),
        "d %d: %d parts: the Jacobi bound %.17g (serial %.17g) and D^-1 "
        "bitwise",
        d, np, b2, b1);
  for (int i = 0; i < n; i++)
    x[i] = uniform(rng);
  mrvi_sblock_matvec(sb, x, ys);
  mrvi_sblock_matvec(sp, x, y1);
  int same = 1;
  for (int t = 1; t <= 3; t += 2) {
    mrvi_sblock_set_parts(sp, np, t);
    mrvi_sblock_matvec(sp, x, y2);
    same = same && memcmp(y1, y2, (size_t)n * sizeof *y1) == 0;
  }
  double e = 0.0, sc = 0.0;
  for (int i = 0; i < n; i++) {
    e = fmax(e, fabs(y1[i] - ys[i]));
    sc = fmax(sc, fabs(ys[i]));
  }
  CHECK(same && e <= 1e-14 * sc,
        "d %d: %d parts: the row-form product the same bits on 1, 2, 3 "
        "threads (%d), the scatter's to %.2e (scale %.2e)",
        d, np, same, e, sc);
  check_sparse_solve(sp, kt, n, np, q, gp, hscale, rng);
  mrvi_sblock_free(sp);
  free(w);
}

/* The matrix-free block (mrvi_sblock_create_free, sweep-cg's Newton matrix
 * where W is springs and anchors) against the assembled sb at q: the
 * gradient bitwise; the product H x to 1e-13 relative; on J = H + s I
 * (positive definite: CG) and J = H - s' I (negative definite: CG meets
 * non-positive curvature and the LU fallback assembles the block from
 * the records) the solutions to 1e-9 relative, D^-1 bitwise and the
 * Jacobi bound to 1e-13 relative (positive definite).  kt, where not NULL:
 * the class in np parts by columns; the block in those parts assembled by
 * parts in reverse, and the block in np parts over the class kc (not in
 * parts: its products formed whole) give the serial product bitwise, and
 * the CG on the parts the same bits on 1, 2, 3 threads
 * (check_sparse_solve). */
static void check_sparse_free(mrvi_terms *kc, mrvi_terms *kt, int np, int n,
                              int d, const law_case *lc, const double *q,
                              const double *g, mrvi_sblock *sb, double hscale,
                              unsigned long long *rng) {
  mrvi_sblock *sf = NULL;
  double *w = calloc(9 * (size_t)n, sizeof *w);
  CHECK(w && mrvi_sblock_create_free(kc, n, d, 512, &sf) == MRVI_OK &&
            mrvi_sblock_free_form(sf),
        "d %d %s: the matrix-free block", d, lc->law);
  if (!w || !sf) {
    free(w);
    mrvi_sblock_free(sf);
    return;
  }
  double *gf = w, *x = w + n, *ya = w + 2 * n, *yf = w + 3 * n;
  double *ba = w + 4 * n, *bf = w + 5 * n, *one = w + 6 * n;
  double *da = w + 7 * n, *df = w + 8 * n;
  char msg[256] = "";
  mrvi_sblock_zero(sf);
  mrvi_sblock_add_terms(sf, kc, q, gf, hscale);
  CHECK(memcmp(g, gf, (size_t)n * sizeof *g) == 0,
        "d %d %s (%g): matrix-free: the gradient bitwise the assembly's", d,
        lc->law, lc->params[1]);
  double hn = 0.0; /* ||H||_inf from the columns */
  for (int f = 0; f < n; f++) {
    for (int i = 0; i < n; i++)
      x[i] = i == f;
    mrvi_sblock_matvec(sb, x, ya);
    double s = 0.0;
    for (int i = 0; i < n; i++)
      s += fabs(ya[i]);
    hn = fmax(hn, s);
  }
  for (int i = 0; i < n; i++) {
    x[i] = uniform(rng);
    one[i] = 1.0;
  }
  mrvi_sblock_matvec(sb, x, ya);
  mrvi_sblock_matvec(sf, x, yf);
  double e = 0.0, sc = 0.0;
  for (int i = 0; i < n; i++) {
    e = fmax(e, fabs(ya[i] - yf[i]));
    sc = fmax(sc, fabs(ya[i]));
  }
  CHECK(sc > 0.0 && e <= 1e-13 * sc,
        "d %d %s (%g): matrix-free product %.2e against the assembled "
        "block's (scale %.2e)",
        d, lc->law, lc->params[1], e, sc);
  const double shift[2] = {2.0 * hn + 1.0, -(2.0 * hn + 1.0)};
  for (int k = 0; k < 2; k++) {
    long nnz = 0;
    mrvi_sblock *bk[2] = {sb, sf};
    double *bb[2] = {ba, bf};
    int st[2];
    for (int b = 0; b < 2; b++) { /* (assembled again: the solve shifts) */
      mrvi_sblock_zero(bk[b]);
      mrvi_sblock_add_terms(bk[b], kc, q, gf, hscale);
      for (int i = 0; i < n; i++)
        bb[b][i] = x[i];
      st[b] = mrvi_sblock_solve(bk[b], one, 0, shift[k], bb[b], 1e-14, msg,
                                sizeof msg);
    }
    e = 0.0;
    double xs = 0.0;
    for (int i = 0; i < n; i++) {
      e = fmax(e, fabs(ba[i] - bf[i]));
      xs = fmax(xs, fabs(ba[i]));
    }
    const long fb = mrvi_sblock_stats(sf)->fallbacks;
    CHECK(st[0] == MRVI_OK && st[1] == MRVI_OK && e <= 1e-9 * xs && fb == k &&
              mrvi_sblock_values(sf, &nnz) == NULL,
          "d %d %s (%g): J + %g I: matrix-free solution %.2e from the "
          "assembled (scale %.2e), %ld LU fallbacks (%d expected) %s",
          d, lc->law, lc->params[1], shift[k], e, xs, fb, k, msg);
    if (k == 1)
      break;
    const double ja = mrvi_sblock_jacobi(sb, da);
    const double jf = mrvi_sblock_jacobi(sf, df);
    CHECK(memcmp(da, df, (size_t)n * sizeof *da) == 0 &&
              fabs(ja - jf) <= 1e-13 * ja,
          "d %d %s (%g): matrix-free Jacobi bound %.17g (assembled %.17g), "
          "D^-1 bitwise",
          d, lc->law, lc->params[1], jf, ja);
  }
  if (kt && np >= 2) {
    mrvi_sblock *sp = NULL;
    mrvi_sblock_zero(sf);
    mrvi_sblock_add_terms(sf, kc, q, gf, hscale);
    mrvi_sblock_matvec(sf, x, ya); /* (the serial product) */
    CHECK(mrvi_sblock_create_free(kt, n, d, 512, &sp) == MRVI_OK &&
              mrvi_sblock_set_parts(sp, np, 2) == MRVI_OK &&
              mrvi_sblock_set_parts(sf, np, 2) == MRVI_OK,
          "d %d %s: matrix-free in %d parts", d, lc->law, np);
    for (int i = 0; sp && i < n; i++)
      ba[i] = 0.0;
    for (int c = np - 1; sp && c >= 0; c--)
      mrvi_sblock_add_terms_part(sp, kt, c, q, ba, hscale, 1);
    int same = sp && memcmp(g, ba, (size_t)n * sizeof *g) == 0;
    for (int t = 1; sp && t <= 3; t++) {
      mrvi_sblock_set_parts(sp, np, t);
      mrvi_sblock_set_parts(sf, np, t);
      mrvi_sblock_matvec(sp, x, yf);
      mrvi_sblock_matvec(sf, x, bf);
      same = same && !memcmp(ya, yf, (size_t)n * sizeof *ya) &&
             !memcmp(ya, bf, (size_t)n * sizeof *ya);
    }
    CHECK(same,
          "d %d %s (%g): matrix-free in %d parts: the gradient and, on 1, 2, "
          "3 threads, the product (the class in parts or whole) bitwise the "
          "serial ones",
          d, lc->law, lc->params[1], np);
    if (sp)
      check_sparse_solve(sp, kt, n, np, q, ba, hscale, rng);
    mrvi_sblock_free(sp);
  }
  mrvi_sblock_zero(sb); /* (sb as it came: the caller's values) */
  mrvi_sblock_add_terms(sb, kc, q, gf, hscale);
  mrvi_sblock_free(sf);
  free(w);
}

static void check_sparse(int d, const law_case *lc, unsigned long long *rng) {
  mrvi_model *m = spring_model_rate(d, lc, rng, MRVI_FAST);
  if (!m)
    return;
  const int n = m->n, ne = m->n_elements;
  int *elems = calloc((size_t)ne, sizeof *elems);
  double *q = calloc((size_t)n, sizeof *q), *g = calloc((size_t)n, sizeof *g);
  double *gr = calloc((size_t)n, sizeof *gr), *v = calloc((size_t)n, sizeof *v);
  double *gp = calloc((size_t)n, sizeof *gp),
         *gm = calloc((size_t)n, sizeof *gm);
  double *Hv = calloc((size_t)n, sizeof *Hv),
         *qh = calloc((size_t)n, sizeof *qh);
  for (int e = 0; e < ne; e++)
    elems[e] = e;
  mrvi_terms *kc = NULL;
  mrvi_sblock *sb = NULL, *sr = NULL;
  CHECK(mrvi_terms_create(m, elems, ne, m->slot, &kc) == MRVI_OK &&
            mrvi_sblock_create(m, elems, ne, 512, &sb) == MRVI_OK &&
            mrvi_sblock_create(m, elems, ne, 512, &sr) == MRVI_OK,
        "d %d %s: create", d, lc->law);
  /* The maps: in dimensions 2 and 3 the compact form (2 x 2 block bases
   * and 2 column lengths a spring, 1 and 1 an anchor; the particles'
   * coordinates on consecutive slots), in 1 the full one (n_in^2). */
  long want = 0;
  for (int e = 0; e < ne; e++) {
    const int ni = MRVI_ELEMENT(m, e)->n_in, nb = ni / d;
    want += d >= 2 ? nb * nb + nb : ni * ni;
  }
  CHECK(!sb || mrvi_sblock_map_ints(sb) == want,
        "d %d %s: maps of %ld ints (%ld expected)", d, lc->law,
        sb ? mrvi_sblock_map_ints(sb) : -1L, want);
  for (int r = 0; kc && sb && sr && r < 4; r++) {
    for (int i = 0; i < n; i++) {
      q[i] = m->q0[i] + 0.3 * uniform(rng);
      v[i] = uniform(rng);
      g[i] = gr[i] = gp[i] = gm[i] = Hv[i] = 0.0;
    }
    const double hscale = -1.9;
    mrvi_sblock_zero(sb);
    mrvi_sblock_zero(sr);
    mrvi_sblock_add_terms(sb, kc, q, g, hscale);
    for (int e = 0; e < ne; e++) { /* the reference */
      const mrvi_element *el = MRVI_ELEMENT(m, e);
      double y[6], ge[6], He[36];
      for (int j = 0; j < el->n_in; j++)
        y[j] = q[m->slot[el->in[j]]];
      mrvi_element_eval(m, el, y, ge, He);
      for (int j = 0; j < el->n_in; j++)
        gr[m->slot[el->in[j]]] += ge[j];
      mrvi_sblock_add_element(sr, e, He, el->n_in, hscale);
    }
    long nnz = 0, nnz_r = 0;
    const double *Ax = mrvi_sblock_values(sb, &nnz);
    const double *Ar = mrvi_sblock_values(sr, &nnz_r);
    CHECK(nnz == nnz_r && memcmp(Ax, Ar, (size_t)nnz * sizeof *Ax) == 0 &&
              memcmp(g, gr, (size_t)n * sizeof *g) == 0,
          "d %d %s (%g): sparse kernel bitwise the generic scatter", d, lc->law,
          lc->params[1]);
    /* The gradient with the Hessian's diagonal and off-diagonal row sums
     * (mrvi_terms_grad_hdiag, sweep-cg's chord): the gradient and the
     * diagonal bitwise those assembled (column f of the values by a product
     * with e_f), the row sums at least the assembled ones. */
    CHECK(mrvi_terms_springs_only(kc), "d %d %s: springs alone", d, lc->law);
    for (int i = 0; i < n; i++)
      gp[i] = gm[i] = qh[i] = 0.0;
    mrvi_terms_grad_hdiag(kc, q, gp, gm, qh, hscale);
    int diag_same = memcmp(g, gp, (size_t)n * sizeof *g) == 0, off_ok = 1;
    for (int f = 0; f < n; f++) {
      for (int i = 0; i < n; i++)
        v[i] = i == f;
      mrvi_sblock_matvec(sb, v, Hv);
      double os = 0.0;
      for (int i = 0; i < n; i++)
        os += i == f ? 0.0 : fabs(Hv[i]);
      diag_same = diag_same && Hv[f] == gm[f];
      off_ok = off_ok && os <= qh[f] * (1.0 + 1e-14);
    }
    CHECK(diag_same && off_ok,
          "d %d %s (%g): fresh diagonal bitwise the assembled (%d), row "
          "sums bound the assembled (%d)",
          d, lc->law, lc->params[1], diag_same, off_ok);
    /* ... and in parts (sweep-cg's row 0 on threads), of about 2 columns
     * (a particle split in 2-D and 3-D) and of about 2 records, taken in
     * reverse: the serial gradient, diagonal and row sums bitwise. */
    for (int by_rec = 0; by_rec <= 1 && mrvi_threads_supported(); by_rec++) {
      mrvi_terms *kt = NULL;
      double *w3 = calloc(3 * (size_t)n, sizeof *w3);
      CHECK(w3 && mrvi_terms_create(m, elems, ne, m->slot, &kt) == MRVI_OK &&
                mrvi_terms_set_threads(kt, 2, 2, by_rec ? 0 : n) == MRVI_OK,
            "d %d %s: threaded create", d, lc->law);
      const int np = kt ? mrvi_terms_parts(kt) : 0;
      CHECK(np >= 2 || (by_rec ? ne : n) < 4, "d %d %s: %d parts by %s", d,
            lc->law, np, by_rec ? "records" : "columns");
      for (int c = np - 1; w3 && c >= 0; c--)
        mrvi_terms_grad_hdiag_part(kt, c, q, w3, w3 + n, w3 + 2 * n, hscale);
      CHECK(np < 2 || (memcmp(w3, gp, (size_t)n * sizeof *gp) == 0 &&
                       memcmp(w3 + n, gm, (size_t)n * sizeof *gm) == 0 &&
                       memcmp(w3 + 2 * n, qh, (size_t)n * sizeof *qh) == 0),
            "d %d %s (%g): %d parts by %s: the serial gradient, diagonal and "
            "row sums bitwise",
            d, lc->law, lc->params[1], np, by_rec ? "records" : "columns");
      /* ... and sweep-cg's row 0 estimate on threads (start_parts): the
       * parts' gradient is mrvi_terms_eval's at unit scale without J
       * bitwise, also with one division per Hooke spring (set_recip, the
       * chord's classes, which mrvi_terms_eval then takes as well). */
      for (int recip = 0; recip <= 1 && w3 && kt && np >= 2; recip++) {
        if (recip)
          mrvi_terms_set_recip(kt);
        for (int i = 0; i < 2 * n; i++)
          w3[i] = 0.0;
        mrvi_terms_eval(kt, q, 1.0, w3, NULL, n, hscale);
        for (int c = np - 1; c >= 0; c--)
          mrvi_terms_grad_part(kt, c, q, w3 + n);
        CHECK(memcmp(w3, w3 + n, (size_t)n * sizeof *w3) == 0,
              "d %d %s (%g): %d parts by %s%s: mrvi_terms_eval's gradient "
              "bitwise",
              d, lc->law, lc->params[1], np, by_rec ? "records" : "columns",
              recip ? ", one division" : "");
      }
      if (w3 && kt && np >= 2 && !by_rec) {
        check_sparse_parts(m, elems, kt, np, q, g, sb, hscale, rng);
        check_sparse_free(kc, kt, np, n, d, lc, q, g, sb, hscale, rng);
      }
      if (w3 && kt && np >= 2)
        check_lin(kt, q, n, np, d, lc, 0, rng);
      if (kt)
        check_gersh(kt, q, n, d, lc, by_rec ? 0 : np, rng);
      /* (the springs alone, without the anchors: a class of Hooke springs
       * where the law is linear) */
      mrvi_terms *kl = NULL;
      int nsp = 0;
      for (int e = 0; e < ne; e++)
        if (m->erecs[e].kind == MRVI_ELEMENT_SPRING)
          w3[nsp++] = e; /* (the indices, read back below) */
      int *sel = calloc((size_t)(nsp > 0 ? nsp : 1), sizeof *sel);
      for (int e = 0; sel && e < nsp; e++)
        sel[e] = (int)w3[e];
      CHECK(sel && mrvi_terms_create(m, sel, nsp, m->slot, &kl) == MRVI_OK &&
                mrvi_terms_set_threads(kl, 2, 2, by_rec ? 0 : n) == MRVI_OK,
            "d %d %s: springs' threaded create", d, lc->law);
      const int npl = kl ? mrvi_terms_parts(kl) : 0;
      if (kl && npl >= 2)
        check_lin(kl, q, n, npl, d, lc, mrvi_terms_set_recip(kl), rng);
      if (sel)
        check_fused(m, sel, nsp, q, n, d, lc);
      mrvi_terms_free(kl);
      free(sel);
      mrvi_terms_free(kt);
      free(w3);
    }
    for (int i = 0; i < n; i++) {
      v[i] = uniform(rng);
      gp[i] = gm[i] = Hv[i] = 0.0;
    }
    /* H v from the values against central differences of the gradient
     * along v. */
    const double h = 1e-7; /* (error h^2 phi''' against round-off / h) */
    for (int i = 0; i < n; i++)
      qh[i] = q[i] + h * v[i];
    mrvi_terms_grad(kc, qh, gp);
    for (int i = 0; i < n; i++)
      qh[i] = q[i] - h * v[i];
    mrvi_terms_grad(kc, qh, gm);
    mrvi_sblock_matvec(sb, v, Hv);
    double e = 0.0, sc = 0.0;
    for (int i = 0; i < n; i++) {
      const double fd = hscale * (gp[i] - gm[i]) / (2 * h);
      e = fmax(e, fabs(Hv[i] - fd));
      sc = fmax(sc, fabs(fd));
    }
    CHECK(e <= 1e-5 * fmax(sc, 1.0),
          "d %d %s (%g): sparse Hessian-vector %.2e against central "
          "differences (scale %.2e)",
          d, lc->law, lc->params[1], e, sc);
    if (r == 0) /* (serial: the block whole) */
      check_sparse_free(kc, NULL, 0, n, d, lc, q, g, sb, hscale, rng);
  }
  mrvi_sblock_free(sb);
  mrvi_sblock_free(sr);
  mrvi_terms_free(kc);
  free(elems);
  free(q);
  free(g);
  free(gr);
  free(v);
  free(gp);
  free(gm);
  free(Hv);
  free(qh);
  mrvi_model_free(m);
}

/* A full class (mrvi_terms_create) of springs and anchors alone is kept
 * without a kterm per element, one of Hooke springs on consecutive
 * columns without kspring records either (its kernels make them from the
 * khooke records, in pieces of 64: solver/terms.c, springs_runs and
 * springs_at): a chain of N_RUN particles in dimension d, its springs of
 * law lc (and anchors on every 7th particle where anchors), against the
 * generic evaluation scattered: the gradient, the Hessian (unit and
 * scaled), the Hessian diagonal of mrvi_terms_grad_hdiag bitwise, the
 * Hessian-vector products of mrvi_terms_hessvec and of the kept blocks
 * and the value to 1e-13; the bytes kept per element. */
enum { N_RUN = 150 };
static void check_runs(int d, const law_case *lc, int anchors,
                       unsigned long long *rng) {
  mrvi_model *m = mrvi_model_create();
  CHECK(m && mrvi_model_set_dimension(m, d) == 0, "d %d: model", d);
  if (!m)
    return;
  for (int i = 0; i < N_RUN; i++) {
    double x[3] = {1.05 * i, 0.1 * (i % 3), 0.0}, v[3] = {0, 0, 0};
    char name[16];
    snprintf(name, sizeof name, "p%d", i);
    CHECK(mrvi_model_add_particle(m, name, 1.0, MRVI_FAST, x, v) >= 0,
          "add particle: %s", mrvi_model_errmsg(m));
  }
  int ok = 1;
  for (int i = 0; i + 1 < N_RUN; i++) {
    ok = ok && mrvi_model_add_spring(m, MRVI_FAST, i, i + 1, lc->law,
                                     lc->params, 1.0 + 0.1 * uniform(rng)) >= 0;
    const double a[3] = {1.05 * i + 0.3, 0.5, -0.2};
    if (anchors && i % 7 == 0)
      ok = ok && mrvi_model_add_anchor_spring(m, MRVI_FAST, i, a, lc->law,
                                              lc->params, 0.6) >= 0;
  }
  CHECK(ok, "%s: springs: %s", lc->law, mrvi_model_errmsg(m));
  const int n = m->n, ne = m->n_elements;
  const size_t nn = (size_t)n * (size_t)n, bn = (size_t)n * sizeof(double);
  int *elems = calloc((size_t)ne, sizeof *elems);
  double *q = calloc((size_t)n, sizeof *q), *v = calloc((size_t)n, sizeof *v);
  double *g = calloc(4 * (size_t)n, sizeof *g), *gr = g + n, *hd = g + 2 * n,
         *hr = g + 3 * n;
  double *H = calloc(nn, sizeof *H), *Hr = calloc(nn, sizeof *Hr);
  double *y = calloc(2 * (size_t)n, sizeof *y), *yr = y + n;
  for (int e = 0; e < ne; e++)
    elems[e] = e;
  for (int i = 0; i < n; i++) {
    q[i] = m->q0[i] + 0.2 * uniform(rng);
    v[i] = uniform(rng);
  }
  mrvi_terms *kc = NULL;
  CHECK(mrvi_terms_create(m, elems, ne, NULL, &kc) == MRVI_OK,
        "d %d %s: create", d, lc->law);
  if (kc && elems && q && v && g && H && Hr && y) {
    const int hooke = !anchors && strcmp(lc->law, "linear") == 0;
    const long per = hooke ? 25 : 97, bytes = mrvi_terms_bytes(kc);
    /* (and the run list: an int a run, one run an anchor here) */
    CHECK(bytes <= per * ne + 8 * (ne / 7 + 2),
          "d %d %s%s: %ld bytes kept for %d elements (%ld each expected)", d,
          lc->law, anchors ? " and anchors" : "", bytes, ne, per);
    const double val_ref = mrvi_model_potential(m, MRVI_FAST, q, gr, Hr);
    mrvi_terms_grad(kc, q, g);
    CHECK(memcmp(g, gr, bn) == 0, "d %d %s: gradient bitwise", d, lc->law);
    memset(g, 0, bn);
    mrvi_terms_eval(kc, q, 1.0, g, H, n, 1.0);
    CHECK(memcmp(g, gr, bn) == 0 && memcmp(H, Hr, nn * sizeof *H) == 0,
          "d %d %s%s: gradient and Hessian bitwise (%.2e, %.2e)", d, lc->law,
          anchors ? " and anchors" : "", rel_diff(g, gr, (size_t)n),
          rel_diff(H, Hr, nn));
    const double sc = 0.37, hs = -1.9;
    memset(g, 0, bn);
    memset(H, 0, nn * sizeof *H);
    mrvi_terms_eval(kc, q, sc, g, H, n, hs);
    for (int i = 0; i < n; i++)
      gr[i] *= sc;
    for (size_t k = 0; k < nn; k++)
      Hr[k] *= hs;
    CHECK(rel_diff(g, gr, (size_t)n) <= 1e-13 && rel_diff(H, Hr, nn) <= 1e-13,
          "d %d %s: scaled gradient %.2e, Hessian %.2e", d, lc->law,
          rel_diff(g, gr, (size_t)n), rel_diff(H, Hr, nn));
    memset(g, 0, bn);
    memset(hd, 0, bn);
    mrvi_terms_grad_hdiag(kc, q, g, hd, NULL, hs);
    for (int i = 0; i < n; i++)
      hr[i] = Hr[(size_t)i * (size_t)n + (size_t)i];
    CHECK(rel_diff(hd, hr, (size_t)n) <= 1e-13,
          "d %d %s: Hessian diagonal %.2e", d, lc->law,
          rel_diff(hd, hr, (size_t)n));
    for (int i = 0; i < n; i++) {
      yr[i] = 0.0;
      for (int j = 0; j < n; j++)
        yr[i] += Hr[(size_t)i * (size_t)n + (size_t)j] * v[j];
    }
    mrvi_terms_hessvec(kc, q, 1, v, n, y, n, hs);
    CHECK(rel_diff(y, yr, (size_t)n) <= 1e-13, "d %d %s: H v %.2e", d, lc->law,
          rel_diff(y, yr, (size_t)n));
    const long nb = mrvi_terms_hessblocks_size(kc);
    double *B = nb > 0 ? calloc((size_t)nb, sizeof *B) : NULL;
    CHECK(B != NULL, "d %d %s: %ld block entries", d, lc->law, nb);
    if (B) {
      memset(y, 0, bn);
      mrvi_terms_hessblocks(kc, q, B);
      mrvi_terms_hessblocks_apply(kc, B, 1, v, n, y, n, hs, NULL);
      CHECK(rel_diff(y, yr, (size_t)n) <= 1e-13, "d %d %s: kept blocks %.2e", d,
            lc->law, rel_diff(y, yr, (size_t)n));
    }
    free(B);
    const double val = mrvi_terms_value(kc, q);
    CHECK(fabs(val - val_ref) <= 1e-13 * fabs(val_ref),
          "d %d %s: value %.17g vs %.17g", d, lc->law, val, val_ref);
  }
  mrvi_terms_free(kc);
  free(elems);
  free(q);
  free(v);
  free(g);
  free(H);
  free(Hr);
  free(y);
  mrvi_model_free(m);
}

/* Every registered law has a case (a new law must be added above). */
static void check_coverage(void) {
  for (int i = 0; i < mrvi_law_count(); i++) {
    const char *name = mrvi_law_get(i)->name;
    int found = 0;
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++)
      found = found || strcmp(cases[c].law, name) == 0;
    CHECK(found, "law %s has a kernel case", name);
  }
}

int main(void) {
  unsigned long long rng = 12345;
  check_coverage();
  for (int d = 1; d <= 3; d++)
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++)
      check_case(d, &cases[c], &rng);
  for (int d = 1; d <= 3; d++)
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++)
      check_sparse(d, &cases[c], &rng);
  for (int d = 1; d <= 3; d++)
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++)
      for (int anchors = 0; anchors <= 1; anchors++)
        check_runs(d, &cases[c], anchors, &rng);
  return test_finish();
}
