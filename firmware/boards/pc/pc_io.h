/* What both boards on the PC do the same way: the plant link's records, the transmit
 * ring to the pty, real-time scheduling, the signals that stop or reset them. */
#ifndef PC_IO_H
#define PC_IO_H

#include <stddef.h>
#include <stdint.h>

struct plant_out {
    uint8_t kind, outputs, flags, session;
    uint16_t aout[2];
    uint32_t tick, extra;
    uint64_t t_ns, next_ns;
};

/* One record to the plant (stdout, non-blocking): 0 when its pipe was full (dropped). */
int plant_write(const struct plant_out *o);
/* Reads what the plant sent (stdin, non-blocking) and hands each whole record to
 * `on_record`; the program ends (exit 0) when the plant closed its side. */
void plant_read(const char *who, void (*on_record)(const uint8_t *record));
/* Writes what the ring holds to `fd` (a pty) until it would block; exits 3 on an error. */
void ring_flush(const char *who, int fd, const uint8_t *ring, size_t size, size_t *head, size_t *len);
/* SCHED_FIFO `prio` when permitted (0: normal), 1 us of timer slack. */
void pc_realtime(const char *who, int prio);
/* SIGTERM, SIGINT, SIGUSR1 and SIGPIPE blocked and delivered on the returned signalfd. */
int pc_signals(const char *who);
uint64_t pc_now_ns(void);

#endif
