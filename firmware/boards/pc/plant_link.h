/* The side channel between a board that runs on the PC (the host board, the simulated
 * AVR) and the simulated plant (lab/serialboard.py): fixed 32-byte little-endian records,
 * board -> plant on stdout, plant -> board on stdin. Not part of the serial protocol: a
 * real board has pins instead. */
#ifndef PLANT_LINK_H
#define PLANT_LINK_H

#include <stdint.h>

#define PLANT_REC 32

/* board -> plant: u8 kind, u8 outputs, u8 flags, u8 session, u16 aout[2], u32 tick,
 * u32 extra, u64 t_ns, u64 next_ns (CLOCK_MONOTONIC; the simulated AVR: its own time,
 * cycles since power-on mapped onto the clock) */
enum {
    REC_TICK = 1,    /* tick `tick` at t_ns; the plant answers with the inputs at next_ns */
    REC_OUTPUTS = 2, /* the outputs changed at t_ns */
    REC_VENT = 3,    /* the heartbeat watchdog vented at tick; extra: the last heartbeat's tick;
                        next_ns: ns from the heartbeat frame's last byte to the pins (0: unknown) */
    REC_RESET = 4,   /* the board restarted (power-on state) at t_ns; extra: the reset cause
                        (firmware/README.md's reset_cause) */
    REC_STATE = 5,   /* the flags or the session changed at t_ns without an output change (a
                        command's effect): sent before the command's ACK reaches the pty, so a
                        plant asked after the host has the ACK already knows it */
};
/* board flag bit beside the core's FS_F_* flags */
#define REC_STREAMING 0x80

/* plant -> board: u8 kind, u8 n, u16 pad, u32 pad, u64 for_ns, u16 counts[8] */
enum {
    REC_ADC = 1,       /* the analog inputs (ADC counts) at for_ns */
    REC_DO_RESET = 2,  /* reset the board as a brown-out or a reset button would */
    REC_DO_STALL = 3,  /* the simulated AVR: its main loop stops (as a firmware bug would) */
};

#endif
