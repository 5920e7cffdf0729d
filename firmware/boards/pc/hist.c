#include "hist.h"

void hist_add(struct hist *h, uint64_t us) {
    h->bins[us < HIST_US ? us : HIST_US]++;
    h->n++;
}

void hist_json(const struct hist *h, FILE *out) {
    long p50 = -1, p99 = -1, max = -1;
    uint64_t acc = 0;
    for (long i = 0; i <= HIST_US; i++) {
        acc += h->bins[i];
        if (p50 < 0 && h->n && acc * 2 >= h->n)
            p50 = i;
        if (p99 < 0 && h->n && acc * 100 >= h->n * 99)
            p99 = i;
        if (h->bins[i])
            max = i;
    }
    fprintf(out, "{\"n\": %llu, \"p50\": %ld, \"p99\": %ld, \"max\": %ld%s}", (unsigned long long)h->n, p50, p99,
            max, max == HIST_US ? ", \"max_is_at_least\": true" : "");
}
