/* An LD_PRELOAD shim that fakes a V4L2 capture device at $FAKE_V4L2_PATH (default
 * /dev/fakevideo0), for tests/hw_fakes: open, ioctl, mmap, poll and close on that path
 * are answered here; everything else goes to libc. It is compiled against the real
 * <linux/videodev2.h>, so the Rust side's struct layouts and ioctl numbers must match
 * the kernel's for anything to work.
 *
 * Formats GREY (rows padded to 16 bytes, to exercise the stride) and YUYV; the driver
 * answer to anything else is GREY, as real drivers adjust S_FMT. Pixel (x, y) of the
 * frame with kernel sequence s has luma (x + 2y + s) mod 256. Frames come at the rate
 * S_PARM asked for; sequence numbers listed in $FAKE_V4L2_DROP (comma separated) are
 * skipped, as frames the driver dropped. After $FAKE_V4L2_VANISH_AT frames the device
 * is unplugged (poll reports POLLERR, DQBUF fails with ENODEV) and the next
 * $FAKE_V4L2_MISSING_OPENS opens fail with ENOENT before it is back. Calls are logged,
 * one per line, to $FAKE_V4L2_LOG. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

#define FAKE_LOG_ENV "FAKE_V4L2_LOG"
#include "fake_log.h"

#define MAX_BUFS 8
#define OFFSET_STEP 0x100000L

static int fake_fd = -1, streaming, vanished, frames_done, missing_opens_left = -1;
static unsigned width = 640, height = 480, pixfmt = V4L2_PIX_FMT_GREY, bpl, sizeimage;
static unsigned num = 1, den = 30, sequence, nbufs;
static struct { void *ptr; int queued; long order; } bufs[MAX_BUFS];
static long queue_order;
static struct timespec next_frame;

static const char *device_path(void) {
    const char *p = getenv("FAKE_V4L2_PATH");
    return p ? p : "/dev/fakevideo0";
}

static int env_int(const char *name, int fallback) {
    const char *v = getenv(name);
    return v ? atoi(v) : fallback;
}

static int dropped(unsigned seq) {
    const char *list = getenv("FAKE_V4L2_DROP");
    char buf[256];
    if (!list) return 0;
    snprintf(buf, sizeof buf, ",%s,", list);
    char needle[32];
    snprintf(needle, sizeof needle, ",%u,", seq);
    return strstr(buf, needle) != NULL;
}

static void set_format(void) {
    if (width > 1024) width = 1024;
    if (height > 1024) height = 1024;
    bpl = pixfmt == V4L2_PIX_FMT_YUYV ? width * 2 : (width + 15) / 16 * 16;
    sizeimage = bpl * height;
}

static int fake_open(const char *path) {
    int (*real_open)(const char *, int, ...) = (int (*)(const char *, int, ...))dlsym(RTLD_NEXT, "open");
    if (missing_opens_left < 0) missing_opens_left = env_int("FAKE_V4L2_MISSING_OPENS", 0);
    if (vanished && missing_opens_left > 0) {
        missing_opens_left--;
        logf_("open ENOENT");
        errno = ENOENT;
        return -1;
    }
    vanished = 0;
    fake_fd = real_open("/dev/null", O_RDWR | O_CLOEXEC);
    logf_("open %s", path);
    return fake_fd;
}

int open(const char *path, int flags, ...) {
    va_list ap;
    va_start(ap, flags);
    int mode = va_arg(ap, int);
    va_end(ap);
    if (strcmp(path, device_path()) == 0) return fake_open(path);
    int (*real)(const char *, int, ...) = (int (*)(const char *, int, ...))dlsym(RTLD_NEXT, "open");
    return real(path, flags, mode);
}

int open64(const char *path, int flags, ...) {
    va_list ap;
    va_start(ap, flags);
    int mode = va_arg(ap, int);
    va_end(ap);
    if (strcmp(path, device_path()) == 0) return fake_open(path);
    int (*real)(const char *, int, ...) = (int (*)(const char *, int, ...))dlsym(RTLD_NEXT, "open64");
    return real(path, flags, mode);
}

int close(int fd) {
    int (*real)(int) = (int (*)(int))dlsym(RTLD_NEXT, "close");
    if (fd >= 0 && fd == fake_fd) {
        logf_("close");
        fake_fd = -1;
        streaming = 0;
        nbufs = 0;
    }
    return real(fd);
}

static void fill(int i) {
    unsigned char *p = bufs[i].ptr;
    for (unsigned y = 0; y < height; y++)
        for (unsigned x = 0; x < width; x++) {
            unsigned char v = (unsigned char)(x + 2 * y + sequence);
            if (pixfmt == V4L2_PIX_FMT_YUYV) {
                p[y * bpl + 2 * x] = v;
                p[y * bpl + 2 * x + 1] = 128;
            } else {
                p[y * bpl + x] = v;
            }
        }
}

static int fail(int e) { errno = e; return -1; }

static int dqbuf(struct v4l2_buffer *b) {
    if (vanished) { logf_("DQBUF ENODEV"); return fail(ENODEV); }
    int best = -1;
    for (unsigned i = 0; i < nbufs; i++)
        if (bufs[i].queued && (best < 0 || bufs[i].order < bufs[best].order)) best = (int)i;
    if (!streaming || best < 0) return fail(EAGAIN);
    while (dropped(sequence)) sequence++;
    fill(best);
    bufs[best].queued = 0;
    /* Stamped with the frame's scheduled end, as a driver stamps the end of a frame. */
    struct timespec now = next_frame;
    memset(b, 0, sizeof *b);
    b->index = (unsigned)best;
    b->type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    b->memory = V4L2_MEMORY_MMAP;
    b->bytesused = sizeimage;
    b->flags = V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | V4L2_BUF_FLAG_TSTAMP_SRC_EOF;
    b->field = V4L2_FIELD_NONE;
    b->timestamp.tv_sec = now.tv_sec;
    b->timestamp.tv_usec = now.tv_nsec / 1000;
    b->sequence = sequence++;
    b->length = sizeimage;
    b->m.offset = (unsigned)(best * OFFSET_STEP);
    frames_done++;
    if (frames_done == env_int("FAKE_V4L2_VANISH_AT", -1)) vanished = 1;
    logf_("DQBUF %d seq %u", best, b->sequence);
    return 0;
}

static int fake_ioctl(unsigned long req, void *arg) {
    switch (req) {
    case VIDIOC_QUERYCAP: {
        struct v4l2_capability *c = arg;
        memset(c, 0, sizeof *c);
        strcpy((char *)c->driver, "fakev4l2");
        strcpy((char *)c->card, "Fake SEM grabber");
        c->device_caps = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING;
        c->capabilities = c->device_caps | V4L2_CAP_DEVICE_CAPS;
        logf_("QUERYCAP");
        return 0;
    }
    case VIDIOC_S_FMT: {
        struct v4l2_format *f = arg;
        if (f->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || streaming) return fail(EINVAL);
        width = f->fmt.pix.width;
        height = f->fmt.pix.height;
        pixfmt = f->fmt.pix.pixelformat == V4L2_PIX_FMT_YUYV ? V4L2_PIX_FMT_YUYV : V4L2_PIX_FMT_GREY;
        set_format();
        f->fmt.pix.width = width;
        f->fmt.pix.height = height;
        f->fmt.pix.pixelformat = pixfmt;
        f->fmt.pix.field = V4L2_FIELD_NONE;
        f->fmt.pix.bytesperline = bpl;
        f->fmt.pix.sizeimage = sizeimage;
        logf_("S_FMT %.4s %ux%u bpl %u", (char *)&pixfmt, width, height, bpl);
        return 0;
    }
    case VIDIOC_S_PARM: {
        struct v4l2_streamparm *p = arg;
        if (p->type != V4L2_BUF_TYPE_VIDEO_CAPTURE) return fail(EINVAL);
        if (p->parm.capture.timeperframe.numerator && p->parm.capture.timeperframe.denominator) {
            num = p->parm.capture.timeperframe.numerator;
            den = p->parm.capture.timeperframe.denominator;
        }
        p->parm.capture.capability = V4L2_CAP_TIMEPERFRAME;
        logf_("S_PARM %u/%u", num, den);
        return 0;
    }
    case VIDIOC_REQBUFS: {
        struct v4l2_requestbuffers *r = arg;
        if (r->memory != V4L2_MEMORY_MMAP || streaming) return fail(EINVAL);
        nbufs = r->count > MAX_BUFS ? MAX_BUFS : r->count;
        for (unsigned i = 0; i < nbufs; i++) {
            bufs[i].ptr = mmap(NULL, sizeimage, PROT_READ | PROT_WRITE, MAP_SHARED | MAP_ANONYMOUS, -1, 0);
            bufs[i].queued = 0;
        }
        r->count = nbufs;
        logf_("REQBUFS %u", nbufs);
        return 0;
    }
    case VIDIOC_QUERYBUF:
    case VIDIOC_QBUF: {
        struct v4l2_buffer *b = arg;
        if (b->index >= nbufs || b->memory != V4L2_MEMORY_MMAP) return fail(EINVAL);
        b->length = sizeimage;
        b->m.offset = (unsigned)(b->index * OFFSET_STEP);
        if (req == VIDIOC_QBUF) {
            bufs[b->index].queued = 1;
            bufs[b->index].order = queue_order++;
        }
        return 0;
    }
    case VIDIOC_DQBUF: return dqbuf(arg);
    case VIDIOC_STREAMON:
        streaming = 1;
        sequence = 0; /* drivers count from 0 again at each STREAMON */
        clock_gettime(CLOCK_MONOTONIC, &next_frame);
        logf_("STREAMON");
        return 0;
    case VIDIOC_STREAMOFF:
        streaming = 0;
        logf_("STREAMOFF");
        return 0;
    default:
        logf_("ioctl %#lx unknown", req);
        return fail(ENOTTY);
    }
}

int ioctl(int fd, unsigned long req, ...) {
    va_list ap;
    va_start(ap, req);
    void *arg = va_arg(ap, void *);
    va_end(ap);
    if (fd >= 0 && fd == fake_fd) return fake_ioctl(req, arg);
    int (*real)(int, unsigned long, ...) = (int (*)(int, unsigned long, ...))dlsym(RTLD_NEXT, "ioctl");
    return real(fd, req, arg);
}

static void *fake_mmap(size_t len, long off) {
    long i = off / OFFSET_STEP;
    if (off % OFFSET_STEP || i < 0 || i >= (long)nbufs || len > sizeimage) { errno = EINVAL; return MAP_FAILED; }
    logf_("mmap %ld", i);
    return bufs[i].ptr;
}

void *mmap(void *addr, size_t len, int prot, int flags, int fd, off_t off) {
    if (fd >= 0 && fd == fake_fd) return fake_mmap(len, (long)off);
    void *(*real)(void *, size_t, int, int, int, off_t) = (void *(*)(void *, size_t, int, int, int, off_t))dlsym(RTLD_NEXT, "mmap");
    return real(addr, len, prot, flags, fd, off);
}

void *mmap64(void *addr, size_t len, int prot, int flags, int fd, off_t off) {
    if (fd >= 0 && fd == fake_fd) return fake_mmap(len, (long)off);
    void *(*real)(void *, size_t, int, int, int, off_t) = (void *(*)(void *, size_t, int, int, int, off_t))dlsym(RTLD_NEXT, "mmap64");
    return real(addr, len, prot, flags, fd, off);
}

/* Waits for the next frame time (or reports the unplugged device). */
int poll(struct pollfd *fds, nfds_t n, int timeout) {
    int (*real)(struct pollfd *, nfds_t, int) = (int (*)(struct pollfd *, nfds_t, int))dlsym(RTLD_NEXT, "poll");
    if (n != 1 || fds[0].fd != fake_fd || fake_fd < 0) return real(fds, n, timeout);
    if (vanished) { fds[0].revents = POLLERR; return 1; }
    if (!streaming) { usleep((useconds_t)timeout * 1000); return 0; }
    long period_ns = (long)(1e9 * num / den);
    struct timespec due = next_frame, deadline;
    due.tv_nsec += period_ns;
    while (due.tv_nsec >= 1000000000) { due.tv_nsec -= 1000000000; due.tv_sec++; }
    clock_gettime(CLOCK_MONOTONIC, &deadline);
    deadline.tv_sec += timeout / 1000;
    deadline.tv_nsec += (long)(timeout % 1000) * 1000000;
    while (deadline.tv_nsec >= 1000000000) { deadline.tv_nsec -= 1000000000; deadline.tv_sec++; }
    if (timeout >= 0 && (due.tv_sec > deadline.tv_sec || (due.tv_sec == deadline.tv_sec && due.tv_nsec > deadline.tv_nsec))) {
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &deadline, NULL);
        return 0;
    }
    next_frame = due;
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next_frame, NULL);
    fds[0].revents = POLLIN;
    return 1;
}
