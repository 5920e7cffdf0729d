#define _GNU_SOURCE
#include "pc_io.h"

#include <errno.h>
#include <sched.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/signalfd.h>
#include <time.h>
#include <unistd.h>

#include "../../core/fs_wire.h"
#include "plant_link.h"

static void die(const char *who, const char *what) {
    fprintf(stderr, "%s: %s: %s\n", who, what, strerror(errno));
    exit(3);
}

uint64_t pc_now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000ull + (uint64_t)ts.tv_nsec;
}

int plant_write(const struct plant_out *o) {
    uint8_t r[PLANT_REC] = {o->kind, o->outputs, o->flags, o->session};
    fs_put_u16(r + 4, o->aout[0]);
    fs_put_u16(r + 6, o->aout[1]);
    fs_put_u32(r + 8, o->tick);
    fs_put_u32(r + 12, o->extra);
    fs_put_u32(r + 16, (uint32_t)o->t_ns);
    fs_put_u32(r + 20, (uint32_t)(o->t_ns >> 32));
    fs_put_u32(r + 24, (uint32_t)o->next_ns);
    fs_put_u32(r + 28, (uint32_t)(o->next_ns >> 32));
    /* never block on the plant: a full pipe drops the record (the caller counts it) */
    return write(STDOUT_FILENO, r, sizeof r) == (ssize_t)sizeof r;
}

void plant_read(const char *who, void (*on_record)(const uint8_t *record)) {
    static uint8_t buf[PLANT_REC * 64];
    static size_t have;
    ssize_t n = read(STDIN_FILENO, buf + have, sizeof buf - have);
    if (n == 0) {
        fprintf(stderr, "%s: the plant closed its side: stopping\n", who);
        exit(0);
    }
    if (n < 0) {
        if (errno == EAGAIN || errno == EINTR)
            return;
        die(who, "reading the plant");
    }
    have += (size_t)n;
    size_t off = 0;
    for (; have - off >= PLANT_REC; off += PLANT_REC)
        on_record(buf + off);
    memmove(buf, buf + off, have - off);
    have -= off;
}

void ring_flush(const char *who, int fd, const uint8_t *ring, size_t size, size_t *head, size_t *len) {
    while (*len) {
        size_t chunk = *len < size - *head ? *len : size - *head;
        ssize_t n = write(fd, ring + *head, chunk);
        if (n <= 0) {
            if (n < 0 && errno != EAGAIN && errno != EINTR)
                die(who, "writing the pty");
            return; /* the pty is full (nobody reads): bytes wait in the ring, then drop */
        }
        *head = (*head + (size_t)n) % size;
        *len -= (size_t)n;
    }
}

void pc_realtime(const char *who, int prio) {
    prctl(PR_SET_TIMERSLACK, 1UL, 0, 0, 0);
    if (prio <= 0)
        return;
    struct sched_param sp = {.sched_priority = prio};
    if (sched_setscheduler(0, SCHED_FIFO, &sp) != 0)
        fprintf(stderr, "%s: SCHED_FIFO %d refused (%s): normal scheduling\n", who, prio, strerror(errno));
}

int pc_signals(const char *who) {
    sigset_t sigs;
    sigemptyset(&sigs);
    sigaddset(&sigs, SIGTERM);
    sigaddset(&sigs, SIGINT);
    sigaddset(&sigs, SIGUSR1);
    sigaddset(&sigs, SIGPIPE);
    sigprocmask(SIG_BLOCK, &sigs, NULL);
    int fd = signalfd(-1, &sigs, SFD_NONBLOCK | SFD_CLOEXEC);
    if (fd < 0)
        die(who, "signalfd");
    return fd;
}
