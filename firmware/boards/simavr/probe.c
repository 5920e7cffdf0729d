#include "probe.h"

#include <stdlib.h>
#include <string.h>

#include <sim_avr.h>

#include "../../core/fs_wire.h"

void line_clear(struct line *l) {
    l->len = l->overlong = 0;
}

int line_byte(struct line *l, uint8_t byte, uint8_t *payload) {
    if (byte != 0) {
        if (l->len < LINE_MAX)
            l->buf[l->len++] = byte;
        else
            l->overlong = 1;
        return -1;
    }
    int n = -1;
    if (l->len && !l->overlong) {
        n = fs_cobs_decode(l->buf, l->len, payload);
        if (n >= 4 && fs_crc16(payload, (size_t)n - 2) == fs_get_u16(payload + n - 2)) {
            n -= 2;
            l->frames++;
        } else {
            n = -1;
            l->bad++;
        }
    } else if (l->overlong) {
        l->bad++;
    }
    line_clear(l);
    return n;
}

void profile_init(struct profile *p, avr_symbol_t **symbols, uint32_t count, uint32_t flash_bytes) {
    memset(p, 0, sizeof *p);
    p->words = flash_bytes / 2;
    p->fn_of = calloc(p->words ? p->words : 1, 1);
    p->name[0] = "(before the first symbol)";
    p->n = 1;
    /* simavr keeps the symbols sorted by address; the text section's lie below 0x800000 */
    for (uint32_t i = 0; i < count && p->n < PROFILE_MAX; i++) {
        const avr_symbol_t *s = symbols[i];
        size_t len = strlen(s->symbol);
        if (s->addr >= flash_bytes || s->symbol[0] == '.' || (len > 4 && !strcmp(s->symbol + len - 2, "__")))
            continue; /* local labels; the linker's constants (__DATA_REGION_LENGTH__ ...) are no code */
        if (p->start[p->n - 1] == s->addr && p->n > 1) {
            p->name[p->n - 1] = s->symbol; /* several names at one address: the last */
            continue;
        }
        p->start[p->n] = s->addr;
        p->name[p->n++] = s->symbol;
    }
    for (int f = 1; f < p->n; f++) {
        uint32_t end = f + 1 < p->n ? p->start[f + 1] : flash_bytes;
        for (uint32_t a = p->start[f]; a < end; a += 2)
            p->fn_of[a / 2] = (uint8_t)f;
    }
}

int profile_find(const struct profile *p, const char *name) {
    for (int f = 0; f < p->n; f++)
        if (!strcmp(p->name[f], name))
            return f;
    return -1;
}

void profile_json(const struct profile *p, FILE *out) {
    fprintf(out, "{");
    const char *sep = "";
    for (int f = 0; f < p->n; f++) {
        if (!p->cycles[f])
            continue;
        fprintf(out, "%s\"%s\": %llu", sep, p->name[f], (unsigned long long)p->cycles[f]);
        sep = ", ";
    }
    fprintf(out, "}");
}
