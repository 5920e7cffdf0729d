/* The simulated board's state and its link to the simulated cell: the one struct both the
 * process (board_simavr.c: pacing, the pty) and simavr's side (mcu.c: the MCU, its pins and
 * lines) read, the MCU's cycles on the host's clock, and the plant link's records (the same
 * as the host board's, ../pc/plant_link.h). Neither of the two files calls the other's
 * functions through here: board_simavr.c drives mcu.c, and both use this one. */
#include <stdio.h>

#include "../../core/fs_wire.h"
#include "../pc/pc_io.h"
#include "../pc/plant_link.h"
#include "sim.h"

struct sim S;

/* ---------------------------------------------------------------- time */
uint64_t now_ns(void) { return pc_now_ns(); }

uint64_t cycle_ns(uint64_t cycle) { /* the MCU's time on the host's clock */
    return S.t0_ns + (uint64_t)((unsigned __int128)cycle * 1000000000u / S.avr->frequency);
}

/* ---------------------------------------------------------------- the plant link */
void to_plant(uint8_t kind, uint32_t tick, uint32_t extra, uint64_t t_ns, uint64_t next_ns) {
    struct plant_out o = {kind, S.outputs,
                          (uint8_t)((S.dev_armed ? FS_F_ARMED : 0) | (S.led ? FS_F_VENTED : 0) |
                                    (S.dev_session ? REC_STREAMING : 0)),
                          S.dev_session, {S.aout[0], S.aout[1]}, tick, extra, t_ns, next_ns};
    if (!plant_write(&o))
        S.stats.plant_dropped++;
}

/* The newest inputs are kept for the next sample's conversions; the rest waits for the
 * next instruction boundary. */
static void plant_record(const uint8_t *r) {
    if (r[0] == REC_ADC) {
        for (int i = 0; i < FS_MAX_CH; i++)
            S.adc_next[i] = fs_get_u16(r + 16 + 2 * i);
        S.adc_next_ns = (uint64_t)fs_get_u32(r + 8) | (uint64_t)fs_get_u32(r + 12) << 32;
    } else if (r[0] == REC_DO_RESET) {
        S.reset_request = 1;
    } else if (r[0] == REC_DO_STALL) {
        S.stall = 1;
        fprintf(stderr, "fsboard-simavr: the firmware's main loop stalls (as a hung firmware would)\n");
    }
}

void from_plant(void) { plant_read("fsboard-simavr", plant_record); }
