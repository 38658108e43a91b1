/*
 * The log-linear histogram layout of runner/histogram.py, once for the C code
 * (interp.c and _trace.c both include it): values below 2 * HIST_SUB are their own
 * bucket; above, each power of two is split into HIST_SUB buckets.  Values from
 * 2^HIST_TOP_BITS ns (about 18 minutes) up share the last bucket; the exact maximum
 * is kept beside it.  Negative values count as 0.
 */
#ifndef RUNNER_HISTOGRAM_H
#define RUNNER_HISTOGRAM_H

#include <stdint.h>

#define HIST_SUB_BITS 7
#define HIST_SUB (1 << HIST_SUB_BITS)
#define HIST_TOP_BITS 40
#define HIST_BUCKETS ((HIST_TOP_BITS - HIST_SUB_BITS + 1) * HIST_SUB)

static inline int hist_index(int64_t v) {
    if (v < 0) v = 0;
    if (v < 2 * HIST_SUB) return (int)v;
    if (v >= (int64_t)1 << HIST_TOP_BITS) return HIST_BUCKETS - 1;
    int shift = 63 - __builtin_clzll((unsigned long long)v) - HIST_SUB_BITS;
    return (shift + 1) * HIST_SUB + (int)(v >> shift) - HIST_SUB;
}

/* The values bucket i holds, both ends included: histogram.bounds() of runner/histogram.py. */
static inline void hist_bounds(int i, int64_t *low, int64_t *high) {
    if (i < 2 * HIST_SUB) {
        *low = *high = i;
        return;
    }
    int shift = i / HIST_SUB - 1;
    *low = (int64_t)(i % HIST_SUB + HIST_SUB) << shift;
    *high = *low + ((int64_t)1 << shift) - 1;
}

#endif
