#define _GNU_SOURCE
#include "pty_link.h"

#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <termios.h>
#include <unistd.h>

static const char *prog = "board";
static char link_path[4096], slave[256];

static void die(const char *what) {
    fprintf(stderr, "%s: %s: %s\n", prog, what, strerror(errno));
    exit(3);
}

static void cleanup(void) {
    char target[256];
    ssize_t n = readlink(link_path, target, sizeof target - 1);
    if (n > 0) {
        target[n] = 0;
        if (strcmp(target, slave) == 0)
            unlink(link_path); /* only our own: a newer board may have replaced it */
    }
}

static void lock_link(void) {
    char lock_path[4200];
    snprintf(lock_path, sizeof lock_path, "%s.lock", link_path);
    int fd = open(lock_path, O_CREAT | O_RDWR | O_CLOEXEC, 0644);
    if (fd < 0)
        die(lock_path);
    if (flock(fd, LOCK_EX | LOCK_NB) != 0) {
        fprintf(stderr, "%s: another board serves %s (%s is locked)\n", prog, link_path, lock_path);
        exit(2);
    }
}

int pty_link_open(const char *who, const char *link, char *slave_name, size_t n) {
    prog = who;
    snprintf(link_path, sizeof link_path, "%s", link);
    lock_link();
    int master = posix_openpt(O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (master < 0 || grantpt(master) != 0 || unlockpt(master) != 0)
        die("posix_openpt");
    if (ptsname_r(master, slave, sizeof slave) != 0)
        die("ptsname_r");
    /* keep the slave open: the line discipline must be raw before any byte goes through
     * (a fresh pty echoes), and a master with no slave open reads EIO */
    int fd = open(slave, O_RDWR | O_NOCTTY);
    struct termios tio;
    if (fd < 0 || tcgetattr(fd, &tio) != 0)
        die("opening the pty slave");
    cfmakeraw(&tio);
    if (tcsetattr(fd, TCSANOW, &tio) != 0)
        die("tcsetattr");
    char tmp[4200];
    snprintf(tmp, sizeof tmp, "%s.%d.tmp", link_path, (int)getpid());
    unlink(tmp);
    if (symlink(slave, tmp) != 0 || rename(tmp, link_path) != 0)
        die(link_path);
    atexit(cleanup);
    snprintf(slave_name, n, "%s", slave);
    return master;
}
