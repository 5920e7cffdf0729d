/* The simulated AVR board: the very image `make firmware` builds (build/avr/fluidsense.elf)
 * executed instruction by instruction by simavr (an ATmega328P at 16 MHz), its USART0
 * behind a pseudo-terminal, its pins wired to the simulated plant over stdin/stdout
 * (../pc/plant_link.h, the same records as the host board's).
 *
 *   fsboard-simavr --elf PATH --link PATH [--f-cpu 16000000] [--vref-mv 5000] [--rt PRIO]
 *                  [--adc-wait-us 200] [--slice-us 500]
 *
 * Pins: the valve outputs are read where the firmware drives them (PORT and DDR of PD2-PD7,
 * PB0, PB3; an undriven pin reads low, as through the MOSFET module's pull-down), the
 * regulator's command from Timer1's PWM on D9/D10 (the duty the datasheet gives for its
 * mode), the vent LED on PB5. The plant puts each sample's sensor voltages on A0-A7 when
 * the timer interrupt starts its conversions. Time: simulated cycles are paced to
 * CLOCK_MONOTONIC in slices; a machine too slow to keep up is counted (lag_us), never
 * hidden. SIGUSR1 or REC_DO_RESET resets the MCU (its reset pin); REC_DO_STALL stops the
 * firmware's main loop (its interrupts go on), which the hardware watchdog must end.
 * SIGTERM or SIGINT print a JSON line of statistics on stderr. */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/signalfd.h>
#include <time.h>
#include <unistd.h>

#include <avr_adc.h>
#include <avr_extint.h>
#include <avr_ioport.h>
#include <avr_timer.h>
#include <avr_uart.h>
#include <sim_avr.h>
#include <sim_elf.h>

#include "../../core/fs_core.h"
#include "../../core/fs_wire.h"
#include "../pc/pc_io.h"
#include "../pc/plant_link.h"
#include "../pc/pty_link.h"
#include "probe.h"
#include "sim.h"

static uint64_t cycle_at(uint64_t t_ns) {
    return t_ns <= S.t0_ns ? 0 : (uint64_t)((unsigned __int128)(t_ns - S.t0_ns) * S.avr->frequency / 1000000000u);
}

static void die(const char *what) {
    fprintf(stderr, "fsboard-simavr: %s: %s\n", what, strerror(errno));
    exit(3);
}

/* ---------------------------------------------------------------- the pty */
static void flush_tx(void) { ring_flush("fsboard-simavr", S.master, S.tx, TX_RING, &S.tx_head, &S.tx_len); }

static void read_pty(void) {
    uint8_t buf[512];
    ssize_t n = read(S.master, buf, sizeof buf);
    for (ssize_t i = 0; i < n; i++) {
        if (S.rx_len == RX_QUEUE) {
            S.stats.rx_dropped++;
            continue;
        }
        S.rx[(S.rx_head + S.rx_len++) % RX_QUEUE] = buf[i];
    }
    if (n > 0)
        rx_start();
}

/* ---------------------------------------------------------------- running */
static void sleep_hook(avr_t *avr, avr_cycle_count_t how_long) {
    (void)avr;
    S.slept += 1 + how_long; /* simavr adds these cycles after this call; pacing is ours */
}

/* One instruction (or a sleep up to the next event, or an interrupt's entry). A stalled
 * main loop spins in place as `rjmp .` would: 2 cycles, the interrupts still served. */
static void step(void) {
    avr_t *avr = S.avr;
    uint32_t pc = avr->pc;
    uint64_t c0 = avr->cycle;
    int fn = profile_fn(&S.prof, pc);
    S.slept = 0;
    if (S.stall && fn == S.fn_main && avr->state == cpu_Running && avr->run == S.run0) {
        avr->cycle += 2;
        avr_cycle_timer_process(avr);
        if (avr->interrupt_state)
            avr_service_interrupts(avr);
        S.prof.stalled += avr->cycle - c0;
    } else {
        avr_run(avr);
        S.prof.asleep += S.slept;
        S.prof.cycles[fn] += avr->cycle - c0 - S.slept;
    }
    mcu_after_step();
}

static void run_until(uint64_t target) {
    while (S.avr->cycle < target) {
        if (S.reset_request) {
            S.reset_request = 0;
            board_reset(FS_RESET_EXTERNAL);
        }
        step();
        if (S.avr->state == cpu_Done || S.avr->state == cpu_Crashed) {
            fprintf(stderr, "fsboard-simavr: the MCU stopped (simavr state %d at pc 0x%x)\n", S.avr->state,
                    S.avr->pc);
            exit(4);
        }
    }
}

static void print_stats(void) {
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    double cpu_s = (double)ru.ru_utime.tv_sec + ru.ru_utime.tv_usec / 1e6 + (double)ru.ru_stime.tv_sec +
                   ru.ru_stime.tv_usec / 1e6;
    FILE *e = stderr;
    fprintf(e, "stats {\"board\": \"simavr\", \"mcu\": \"%s\", \"f_cpu\": %u, \"cycles\": %llu, \"asleep\": %llu, "
            "\"stalled\": %llu, \"ticks\": %llu, \"stale\": %llu, \"samples_sent\": %llu, \"resets\": %llu, "
            "\"watchdog_resets\": %llu, \"vents\": %llu, \"tx_bytes\": %llu, \"rx_bytes\": %llu, "
            "\"tx_dropped\": %llu, \"rx_dropped\": %llu, \"plant_dropped\": %llu, \"frames_out\": %u, "
            "\"bad_frames_out\": %u, \"frames_in\": %u, \"seq_gaps\": %llu, \"tick_gaps\": %llu, "
            "\"flagged_tx_dropped\": %llu, \"flagged_adc_late\": %llu, \"uart_cycles_per_byte\": %llu, "
            "\"cpu_s\": %.3f, \"lag_max_us\": %llu, \"lag_over_100ms\": %llu, \"lag_us\": ", S.avr->mmcu, S.avr->frequency, (unsigned long long)S.avr->cycle,
            (unsigned long long)S.prof.asleep, (unsigned long long)S.prof.stalled, (unsigned long long)S.stats.ticks,
            (unsigned long long)S.stats.stale, (unsigned long long)S.stats.samples,
            (unsigned long long)S.stats.resets, (unsigned long long)S.stats.watchdog_resets,
            (unsigned long long)S.stats.vents, (unsigned long long)S.stats.tx_bytes,
            (unsigned long long)S.stats.rx_bytes, (unsigned long long)S.stats.tx_dropped,
            (unsigned long long)S.stats.rx_dropped, (unsigned long long)S.stats.plant_dropped, S.tx_line.frames,
            S.tx_line.bad, S.rx_line.frames, (unsigned long long)S.stats.seq_gaps,
            (unsigned long long)S.stats.tick_gaps, (unsigned long long)S.stats.flagged_tx_dropped,
            (unsigned long long)S.stats.flagged_adc_late, (unsigned long long)S.uart->cycles_per_byte, cpu_s,
            (unsigned long long)S.stats.lag_max_us, (unsigned long long)S.stats.lag_over_100ms);
    hist_json(&S.stats.lag, e);
    fprintf(e, ", \"set_outputs_to_pins_us\": ");
    hist_json(&S.stats.cmd_to_pin, e);
    fprintf(e, ", \"heartbeat_to_vent_us\": [");
    for (uint64_t i = 0; i < S.stats.vents && i < 16; i++)
        fprintf(e, "%s%llu", i ? ", " : "", (unsigned long long)S.stats.hb_to_vent_us[i]);
    fprintf(e, "]");
    fprintf(e, ", \"cycles_by_function\": ");
    profile_json(&S.prof, e);
    fprintf(e, "}\n");
    fflush(e);
}

static void usage(void) {
    fprintf(stderr, "usage: fsboard-simavr --elf PATH --link PATH [--f-cpu HZ] [--vref-mv MV] [--rt PRIO] "
            "[--adc-wait-us US] [--slice-us US]\n");
    exit(2);
}

int main(int argc, char **argv) {
    const char *elf = NULL, *link = NULL;
    int rt = 0, vref_mv = 5000, slice_us = 500;
    long f_cpu = 16000000;
    S.adc_wait_us = 200;
    for (int i = 1; i < argc; i += 2) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!v)
            usage();
        if (!strcmp(a, "--elf"))
            elf = v;
        else if (!strcmp(a, "--link"))
            link = v;
        else if (!strcmp(a, "--f-cpu"))
            f_cpu = atol(v);
        else if (!strcmp(a, "--vref-mv"))
            vref_mv = atoi(v);
        else if (!strcmp(a, "--rt"))
            rt = atoi(v);
        else if (!strcmp(a, "--adc-wait-us"))
            S.adc_wait_us = atoi(v);
        else if (!strcmp(a, "--slice-us"))
            slice_us = atoi(v);
        else
            usage();
    }
    if (!elf || !link || f_cpu < 1000000 || f_cpu > 20000000 || vref_mv < 1000 || vref_mv > 5500 || S.adc_wait_us < 0 || S.adc_wait_us > 100000 ||
        slice_us < 20 || slice_us > 100000)
        usage();
    char slave[256];
    S.master = pty_link_open("fsboard-simavr", link, slave, sizeof slave);
    mcu_load(elf, (uint32_t)f_cpu, (uint32_t)vref_mv);
    pc_realtime("fsboard-simavr", rt);
    S.avr->sleep = sleep_hook;
    int sfd = pc_signals("fsboard-simavr");
    fcntl(STDIN_FILENO, F_SETFL, fcntl(STDIN_FILENO, F_GETFL) | O_NONBLOCK);
    fcntl(STDOUT_FILENO, F_SETFL, fcntl(STDOUT_FILENO, F_GETFL) | O_NONBLOCK);
    S.t0_ns = now_ns();
    to_plant(REC_RESET, 0, FS_RESET_POWER, cycle_ns(0), 0);
    fprintf(stderr, "ready %s -> %s\n", link, slave);
    uint64_t slice_ns = (uint64_t)slice_us * 1000;
    for (;;) {
        uint64_t now = now_ns(), at = cycle_ns(S.avr->cycle);
        if (at < now) {
            uint64_t lag_us = (now - at) / 1000; /* how far behind the host's clock the MCU is */
            hist_add(&S.stats.lag, lag_us);
            S.stats.lag_max_us = lag_us > S.stats.lag_max_us ? lag_us : S.stats.lag_max_us;
            S.stats.lag_over_100ms += lag_us > 100000;
            run_until(cycle_at(now));
        }
        flush_tx();
        uint64_t next = cycle_ns(S.avr->cycle) + slice_ns, after = now_ns();
        struct timespec ts = {0, next > after ? (long)(next - after) : 0};
        struct pollfd p[3] = {
            {.fd = S.master, .events = (short)(POLLIN | (S.tx_len ? POLLOUT : 0))},
            {.fd = STDIN_FILENO, .events = POLLIN},
            {.fd = sfd, .events = POLLIN},
        };
        if (ppoll(p, 3, &ts, NULL) < 0) {
            if (errno == EINTR)
                continue;
            die("poll");
        }
        if (p[2].revents & POLLIN) {
            struct signalfd_siginfo si;
            while (read(sfd, &si, sizeof si) == (ssize_t)sizeof si) {
                if (si.ssi_signo == SIGUSR1) {
                    S.reset_request = 1;
                } else if (si.ssi_signo != SIGPIPE) {
                    print_stats();
                    return 0;
                }
            }
        }
        if (p[1].revents & (POLLIN | POLLHUP))
            from_plant();
        if (p[0].revents & POLLIN)
            read_pty();
    }
}
