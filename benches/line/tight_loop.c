/*
 * The tight-loop anchor of `cargo bench --bench line mbpoll`: libmodbus reading the 8 count
 * registers of each unit in turn, back to back, with no pause (mbpoll cannot: its shortest
 * pause is 10 ms after every unit), for a given time, then exits. Without a pause it is the
 * like-for-like anchor for the gateway polling as fast as answered. It prints nothing while
 * it runs (mbpoll's printing is part of its cost; this client's is not there to compare).
 *
 *   tight_loop tcp HOST PORT     UNITS REGISTER SECONDS
 *   tight_loop rtu DEVICE BAUD   UNITS REGISTER SECONDS     (8N1)
 *
 * Built by the bench: cc -O2 tight_loop.c $(pkg-config --cflags --libs libmodbus).
 * Exit: 0 when at least one read was answered, 1 when none was, 2 on bad arguments or setup.
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <modbus.h>

#define COUNT_REGISTERS 8

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + (double)t.tv_nsec / 1e9;
}

/* Parses a whole decimal argument within [lo, hi]; -1 if it is not one. */
static long arg(const char *s, long lo, long hi)
{
    char *end;
    long v;
    errno = 0;
    v = strtol(s, &end, 10);
    if (errno != 0 || end == s || *end != '\0' || v < lo || v > hi)
        return -1;
    return v;
}

int main(int argc, char **argv)
{
    modbus_t *ctx;
    uint16_t regs[COUNT_REGISTERS];
    long units, reg, secs, answered = 0, failed = 0;
    double until;

    if (argc != 7) {
        fprintf(stderr, "usage: %s tcp HOST PORT | rtu DEVICE BAUD, then UNITS REGISTER SECONDS\n",
                argv[0]);
        return 2;
    }
    units = arg(argv[4], 1, 247);
    reg = arg(argv[5], 0, 65535 - COUNT_REGISTERS);
    secs = arg(argv[6], 1, 3600); /* bounded: the bench stops it after its window anyway */
    if (units < 0 || reg < 0 || secs < 0) {
        fprintf(stderr, "%s: UNITS 1..247, REGISTER 0..65527, SECONDS 1..3600\n", argv[0]);
        return 2;
    }
    if (strcmp(argv[1], "tcp") == 0) {
        long port = arg(argv[3], 1, 65535);
        ctx = port < 0 ? NULL : modbus_new_tcp(argv[2], (int)port);
    } else if (strcmp(argv[1], "rtu") == 0) {
        long baud = arg(argv[3], 300, 4000000);
        ctx = baud < 0 ? NULL : modbus_new_rtu(argv[2], (int)baud, 'N', 8, 1);
    } else {
        ctx = NULL;
    }
    if (ctx == NULL) {
        fprintf(stderr, "%s: cannot set up %s %s %s\n", argv[0], argv[1], argv[2], argv[3]);
        return 2;
    }
    /* mbpoll's -o 0.1: a unit that does not answer within 100 ms is skipped. */
    if (modbus_set_response_timeout(ctx, 0, 100000) != 0 || modbus_connect(ctx) != 0) {
        fprintf(stderr, "%s: %s\n", argv[0], modbus_strerror(errno));
        modbus_free(ctx);
        return 2;
    }
    until = now() + (double)secs;
    while (now() < until) {
        for (long unit = 1; unit <= units; unit++) {
            if (modbus_set_slave(ctx, (int)unit) != 0) {
                fprintf(stderr, "%s: unit %ld: %s\n", argv[0], unit, modbus_strerror(errno));
                modbus_close(ctx);
                modbus_free(ctx);
                return 2;
            }
            /* A failed read is counted and the loop goes on, as mbpoll's does. */
            if (modbus_read_registers(ctx, (int)reg, COUNT_REGISTERS, regs) == COUNT_REGISTERS)
                answered++;
            else
                failed++;
        }
    }
    fprintf(stderr, "%s: %ld answered, %ld failed\n", argv[0], answered, failed);
    modbus_close(ctx);
    modbus_free(ctx);
    return answered > 0 ? 0 : 1;
}
