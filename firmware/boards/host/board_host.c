/* Host board: the firmware core as a Linux process behind a pseudo-terminal, its analog
 * inputs and outputs wired to the simulated plant through stdin/stdout (plant_link.h).
 * The daemon opens the pty (through the symlink --link) exactly as it opens a USB
 * serial device, and talks to the same protocol code, byte for byte.
 *
 *   fsboard-host --link PATH [--adc-bits 10] [--adc-inputs 8] [--rt PRIO] [--adc-wait-us 200]
 *
 * The sample timer is a timerfd on CLOCK_MONOTONIC at the configured rate. The plant
 * evaluates the inputs at each tick's deadline; the board waits up to --adc-wait-us after
 * the deadline for them (the AVR's two conversions take 208 us), then samples the newest
 * values it has (counted as stale: the emulated world lagged, never the protocol).
 * SIGUSR1 (or a REC_DO_RESET record) resets the board as a brown-out would; SIGTERM or
 * SIGINT end it with a JSON line of statistics on stderr. */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/signalfd.h>
#include <sys/timerfd.h>
#include <time.h>
#include <unistd.h>

#include "../../core/fs_core.h"
#include "../../core/fs_wire.h"
#include "../pc/hist.h"
#include "../pc/pc_io.h"
#include "../pc/pty_link.h"
#include "../pc/plant_link.h"

#define MAX_RATE_HZ 10000
#define TX_RING 8192
#define BACKLOG_MAX 50 /* ticks caught up after a stall; older ones are skipped (a gap) */

static struct fs_core core;
static struct fs_board_info info = {.name = "host", .adc_bits = 10, .n_adc = 8, .n_outputs = 8, .n_aout = 2,
                                    .max_rate_hz = MAX_RATE_HZ, .reset_cause = FS_RESET_POWER};
static int master = -1, timer = -1;
static uint64_t period_ns, t0_ns;
static uint32_t next_tick;
static uint8_t adc_mask = 1;
static int adc_wait_us = 200;
/* the newest plant record: the inputs at for_ns */
static uint16_t analog[FS_MAX_CH];
static uint64_t analog_ns;
static uint8_t outputs;
static uint16_t aout[FS_MAX_AOUT];
static uint8_t tx[TX_RING];
static size_t tx_head, tx_len;
static struct {
    uint64_t ticks, stale, skipped, tx_dropped, plant_dropped, resets, vents;
    struct hist wake_late;
} stats;

static uint64_t now_ns(void) { return pc_now_ns(); }

static void die(const char *what) {
    fprintf(stderr, "fsboard-host: %s: %s\n", what, strerror(errno));
    exit(3);
}

/* ---------------------------------------------------------------- the plant link */
static uint8_t state_flags(void) {
    return (uint8_t)((core.armed ? FS_F_ARMED : 0) | (core.vented ? FS_F_VENTED : 0) |
                     (core.streaming ? REC_STREAMING : 0));
}

static uint8_t told_flags, told_session; /* as the plant last heard them */

static void to_plant(uint8_t kind, uint32_t tick, uint32_t extra, uint64_t t_ns, uint64_t next_ns) {
    struct plant_out o = {kind, outputs, state_flags(), core.session, {aout[0], aout[1]}, tick, extra, t_ns,
                          next_ns};
    told_flags = o.flags;
    told_session = o.session;
    if (!plant_write(&o))
        stats.plant_dropped++;
}

/* After the host's bytes: a command that changed the session or the flags and no output
 * (STOP ends the session after its ACK is built) is told to the plant now, before its ACK
 * goes to the pty, not at the next tick: a host holding the ACK may ask the plant first. */
static void tell_state(void) {
    if (state_flags() != told_flags || core.session != told_session)
        to_plant(REC_STATE, core.tick, 0, now_ns(), 0);
}

static void board_reset(void);

static void plant_record(const uint8_t *r) {
    if (r[0] == REC_ADC) {
        for (int i = 0; i < FS_MAX_CH; i++)
            analog[i] = fs_get_u16(r + 16 + 2 * i);
        analog_ns = (uint64_t)fs_get_u32(r + 8) | (uint64_t)fs_get_u32(r + 12) << 32;
    } else if (r[0] == REC_DO_RESET) {
        board_reset();
    }
}

static void from_plant(void) { plant_read("fsboard-host", plant_record); }

/* ---------------------------------------------------------------- board hooks */
void fs_board_outputs(uint8_t levels) {
    outputs = levels;
    to_plant(REC_OUTPUTS, core.tick, 0, now_ns(), 0);
}

void fs_board_aout(uint8_t channel, uint16_t value) {
    aout[channel] = value;
    to_plant(REC_OUTPUTS, core.tick, 0, now_ns(), 0);
}

int fs_board_configure(uint16_t rate_hz, uint8_t mask) {
    if (rate_hz == 0 || rate_hz > MAX_RATE_HZ)
        return -1;
    period_ns = 1000000000ull / rate_hz;
    t0_ns = now_ns() + period_ns;
    next_tick = 0;
    adc_mask = mask;
    struct itimerspec its = {
        .it_value = {.tv_sec = (time_t)(t0_ns / 1000000000ull), .tv_nsec = (long)(t0_ns % 1000000000ull)},
        .it_interval = {.tv_sec = (time_t)(period_ns / 1000000000ull), .tv_nsec = (long)(period_ns % 1000000000ull)},
    };
    if (timer >= 0 && timerfd_settime(timer, TFD_TIMER_ABSTIME, &its, NULL) != 0)
        die("timerfd_settime");
    to_plant(REC_TICK, 0xFFFFFFFFu, 0, now_ns(), t0_ns); /* ask for the first tick's inputs */
    return 0;
}

int fs_board_send(const uint8_t *frame, uint8_t len) {
    if (TX_RING - tx_len < len) {
        stats.tx_dropped++;
        return 0;
    }
    for (uint8_t i = 0; i < len; i++)
        tx[(tx_head + tx_len + i) % TX_RING] = frame[i];
    tx_len += len;
    return 1;
}

void fs_board_vented(uint32_t tick, uint32_t last_hb_tick) {
    stats.vents++;
    fprintf(stderr, "fsboard-host: no heartbeat since tick %u: vented at tick %u\n", last_hb_tick, tick);
    to_plant(REC_VENT, tick, last_hb_tick, now_ns(), 0);
}

static void flush_tx(void) { ring_flush("fsboard-host", master, tx, TX_RING, &tx_head, &tx_len); }

static void board_reset(void) {
    stats.resets++;
    tx_head = tx_len = 0; /* a reset loses what the UART had not sent */
    info.reset_cause = FS_RESET_EXTERNAL;
    fs_core_init(&core, &info);
    to_plant(REC_RESET, 0, FS_RESET_EXTERNAL, now_ns(), 0);
}

/* ---------------------------------------------------------------- sampling */
static void take_sample(uint32_t tick, uint64_t deadline) {
    uint16_t counts[FS_MAX_CH];
    uint8_t n = 0;
    for (uint8_t ch = 0; ch < FS_MAX_CH; ch++)
        if (adc_mask & (1u << ch))
            counts[n++] = analog[ch];
    if (analog_ns != deadline)
        stats.stale++;
    stats.ticks++;
    fs_core_tick(&core, tick, counts, 0);
    to_plant(REC_TICK, tick, 0, deadline, deadline + period_ns);
}

static void on_timer(void) {
    uint64_t expired;
    if (read(timer, &expired, sizeof expired) != (ssize_t)sizeof expired)
        return;
    uint64_t late = (now_ns() - (t0_ns + (uint64_t)next_tick * period_ns)) / 1000;
    hist_add(&stats.wake_late, late);
    if (expired > BACKLOG_MAX) { /* the process was not scheduled: those ticks have no sample */
        stats.skipped += expired - BACKLOG_MAX;
        next_tick += (uint32_t)(expired - BACKLOG_MAX);
        expired = BACKLOG_MAX;
    }
    for (uint64_t i = 0; i < expired; i++) {
        uint64_t deadline = t0_ns + (uint64_t)next_tick * period_ns;
        if (i + 1 == expired && analog_ns != deadline) {
            /* the newest tick: give the plant the conversion time to deliver its inputs */
            uint64_t until = deadline + (uint64_t)adc_wait_us * 1000;
            struct pollfd p = {.fd = STDIN_FILENO, .events = POLLIN};
            while (analog_ns != deadline) {
                uint64_t now = now_ns();
                if (now >= until)
                    break;
                struct timespec ts = {.tv_sec = 0, .tv_nsec = (long)(until - now)};
                if (ppoll(&p, 1, &ts, NULL) > 0)
                    from_plant();
            }
        }
        take_sample(next_tick++, deadline);
    }
    flush_tx();
}

static void print_stats(void) {
    fprintf(stderr, "stats {\"ticks\": %llu, \"stale\": %llu, \"skipped\": %llu, \"tx_dropped\": %llu, "
            "\"plant_dropped\": %llu, \"resets\": %llu, \"vents\": %llu, \"rx_errors\": %u, \"wake_late_us\": ",
            (unsigned long long)stats.ticks, (unsigned long long)stats.stale, (unsigned long long)stats.skipped,
            (unsigned long long)stats.tx_dropped, (unsigned long long)stats.plant_dropped,
            (unsigned long long)stats.resets, (unsigned long long)stats.vents, core.rx_errors);
    hist_json(&stats.wake_late, stderr);
    fprintf(stderr, "}\n");
    fflush(stderr);
}

/* ---------------------------------------------------------------- set-up */
static char link_path[4096], slave_name[256];

static void usage(void) {
    fprintf(stderr, "usage: fsboard-host --link PATH [--adc-bits N] [--adc-inputs N] [--rt PRIO] "
            "[--adc-wait-us US]\n");
    exit(2);
}

int main(int argc, char **argv) {
    int rt = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!v)
            usage();
        if (!strcmp(a, "--link"))
            snprintf(link_path, sizeof link_path, "%s", v);
        else if (!strcmp(a, "--adc-bits"))
            info.adc_bits = (uint8_t)atoi(v);
        else if (!strcmp(a, "--adc-inputs"))
            info.n_adc = (uint8_t)atoi(v);
        else if (!strcmp(a, "--rt"))
            rt = atoi(v);
        else if (!strcmp(a, "--adc-wait-us"))
            adc_wait_us = atoi(v);
        else
            usage();
        i++;
    }
    if (!link_path[0] || info.adc_bits < 8 || info.adc_bits > 16 || info.n_adc < 1 || info.n_adc > FS_MAX_CH ||
        adc_wait_us < 0 || adc_wait_us > 100000)
        usage();
    master = pty_link_open("fsboard-host", link_path, slave_name, sizeof slave_name);
    pc_realtime("fsboard-host", rt);
    fcntl(STDIN_FILENO, F_SETFL, fcntl(STDIN_FILENO, F_GETFL) | O_NONBLOCK);
    fcntl(STDOUT_FILENO, F_SETFL, fcntl(STDOUT_FILENO, F_GETFL) | O_NONBLOCK);
    int sfd = pc_signals("fsboard-host");
    timer = timerfd_create(CLOCK_MONOTONIC, TFD_NONBLOCK | TFD_CLOEXEC);
    if (timer < 0)
        die("timerfd_create");
    fs_core_init(&core, &info);
    fprintf(stderr, "ready %s -> %s\n", link_path, slave_name);
    for (;;) {
        struct pollfd p[4] = {
            {.fd = timer, .events = POLLIN},
            {.fd = master, .events = (short)(POLLIN | (tx_len ? POLLOUT : 0))},
            {.fd = STDIN_FILENO, .events = POLLIN},
            {.fd = sfd, .events = POLLIN},
        };
        if (poll(p, 4, -1) < 0) {
            if (errno == EINTR)
                continue;
            die("poll");
        }
        if (p[3].revents & POLLIN) {
            struct signalfd_siginfo si;
            while (read(sfd, &si, sizeof si) == (ssize_t)sizeof si) {
                if (si.ssi_signo == SIGUSR1) {
                    board_reset();
                } else if (si.ssi_signo != SIGPIPE) {
                    print_stats();
                    return 0;
                }
            }
        }
        if (p[2].revents & (POLLIN | POLLHUP))
            from_plant();
        if (p[1].revents & POLLIN) {
            uint8_t buf[512];
            ssize_t n = read(master, buf, sizeof buf);
            for (ssize_t i = 0; i < n; i++)
                fs_core_rx(&core, buf[i]);
            tell_state();
        }
        if (p[0].revents & POLLIN)
            on_timer();
        if (tx_len)
            flush_tx();
    }
}
