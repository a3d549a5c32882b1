/* The fakes' call log, shared by every fake library: one line per call, appended to
 * the file the environment variable FAKE_LOG_ENV names (each fake defines FAKE_LOG_ENV
 * before including this), so a test can read back what was called, in order.
 * No file named: nothing is logged. */
#ifndef FAKE_LOG_H
#define FAKE_LOG_H

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>

static void logf_(const char *fmt, ...) {
    const char *path = getenv(FAKE_LOG_ENV);
    if (!path) return;
    FILE *f = fopen(path, "a");
    if (!f) return;
    va_list ap;
    va_start(ap, fmt);
    vfprintf(f, fmt, ap);
    va_end(ap);
    fputc('\n', f);
    fclose(f);
}

#endif
