/* A latency histogram in 1 us bins, for the boards that run on the PC. */
#ifndef HIST_H
#define HIST_H

#include <stdint.h>
#include <stdio.h>

#define HIST_US 10000

struct hist {
    uint64_t n;
    uint32_t bins[HIST_US + 1]; /* the last: HIST_US or more */
};

void hist_add(struct hist *h, uint64_t us);
/* {"n": .., "p50": .., "p99": .., "max": ..} in us (-1 when empty) */
void hist_json(const struct hist *h, FILE *out);

#endif
