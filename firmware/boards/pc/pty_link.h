/* The PC side of a board that runs on Linux (the host board, the simulated AVR): a
 * pseudo-terminal whose slave the daemon opens as it opens a USB serial device, linked
 * at a path of the user's choice, and a lock so that two boards never serve one link. */
#ifndef PTY_LINK_H
#define PTY_LINK_H

#include <stddef.h>

/* Locks PATH.lock (exits 2 when another board holds it), opens a raw pty, links its slave
 * at `link` and removes the link at exit (when it is still ours). Returns the master,
 * non-blocking; the slave stays open (a master without one reads EIO). `who` prefixes
 * the messages; on failure the program exits 3. */
int pty_link_open(const char *who, const char *link, char *slave_name, size_t n);

#endif
