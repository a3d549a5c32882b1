/* A stand-in for OpenHaptics' libHD.so, loaded by nanoforce's openhaptics backend in
 * place of the real one (haptic.library = its path). Like the real scheduler it runs
 * the scheduled callbacks on its own thread every millisecond. The test drives it
 * through the fake_hd_* functions: the stylus position, velocity and buttons, errors
 * to raise in the next frame, a pause of the servo thread; and reads back what the
 * device was told (force, force output, scheduler and device state). */
#include <pthread.h>
#include <string.h>
#include <time.h>

typedef unsigned int HHD;
typedef struct { unsigned int errorCode; int internalErrorCode; HHD hHD; } HDErrorInfo;
typedef unsigned int (*HDSchedulerCallback)(void *);

#define HD_CURRENT_BUTTONS 0x2000
#define HD_CURRENT_POSITION 0x2050
#define HD_CURRENT_VELOCITY 0x2051
#define HD_CURRENT_FORCE 0x2700
#define HD_FORCE_OUTPUT 0x4000
#define HD_COMM_CONFIG_ERROR 0x0303
#define HD_ILLEGAL_BEGIN 0x0400
#define HD_INVALID_HANDLE 0xFFFFFFFFu

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_t servo;
static int running, paused, initialized, force_output, in_frame;
static double position[3], velocity[3], force[3];
static int buttons;
static long frames;
static HDErrorInfo errors[16];
static int n_errors;
static HDErrorInfo pending; /* raised at the next hdEndFrame */
static struct { HDSchedulerCallback fn; void *data; int active; } callbacks[4];

static void push_error(unsigned code, int internal) {
    if (n_errors < 16) errors[n_errors++] = (HDErrorInfo){code, internal, 0};
}

HHD hdInitDevice(const char *name) {
    pthread_mutex_lock(&lock);
    HHD h = 0;
    if (name && strcmp(name, "Default PHANToM") != 0) {
        push_error(HD_COMM_CONFIG_ERROR, -1);
        h = HD_INVALID_HANDLE;
    } else {
        initialized = 1;
        force_output = 1; /* as the real library: on after init */
    }
    pthread_mutex_unlock(&lock);
    return h;
}
void hdDisableDevice(HHD h) { (void)h; pthread_mutex_lock(&lock); initialized = 0; pthread_mutex_unlock(&lock); }
HDErrorInfo hdGetError(void) {
    pthread_mutex_lock(&lock);
    HDErrorInfo e = {0, 0, 0};
    if (n_errors > 0) {
        e = errors[0];
        memmove(errors, errors + 1, sizeof errors[0] * (size_t)--n_errors);
    }
    pthread_mutex_unlock(&lock);
    return e;
}
const char *hdGetErrorString(unsigned code) {
    switch (code) {
    case 0x0201: return "Exceeded max force";
    case 0x0302: return "Communication error";
    case 0x0303: return "Device not found in the configuration";
    default: return "Fake HD error";
    }
}
void hdBeginFrame(HHD h) { (void)h; pthread_mutex_lock(&lock); if (in_frame) push_error(HD_ILLEGAL_BEGIN, 0); in_frame = 1; pthread_mutex_unlock(&lock); }
void hdEndFrame(HHD h) {
    (void)h;
    pthread_mutex_lock(&lock);
    in_frame = 0;
    frames++;
    if (pending.errorCode) { push_error(pending.errorCode, pending.internalErrorCode); pending.errorCode = 0; }
    pthread_mutex_unlock(&lock);
}
void hdGetDoublev(unsigned p, double *v) {
    pthread_mutex_lock(&lock);
    if (p == HD_CURRENT_POSITION) memcpy(v, position, sizeof position);
    if (p == HD_CURRENT_VELOCITY) memcpy(v, velocity, sizeof velocity);
    if (p == HD_CURRENT_FORCE) memcpy(v, force, sizeof force);
    pthread_mutex_unlock(&lock);
}
void hdGetIntegerv(unsigned p, int *v) {
    pthread_mutex_lock(&lock);
    if (p == HD_CURRENT_BUTTONS) *v = buttons;
    pthread_mutex_unlock(&lock);
}
void hdSetDoublev(unsigned p, const double *v) {
    pthread_mutex_lock(&lock);
    if (p == HD_CURRENT_FORCE) memcpy(force, v, sizeof force);
    pthread_mutex_unlock(&lock);
}
void hdEnable(unsigned cap) { pthread_mutex_lock(&lock); if (cap == HD_FORCE_OUTPUT) force_output = 1; pthread_mutex_unlock(&lock); }
void hdDisable(unsigned cap) { pthread_mutex_lock(&lock); if (cap == HD_FORCE_OUTPUT) force_output = 0; pthread_mutex_unlock(&lock); }
unsigned long hdScheduleAsynchronous(HDSchedulerCallback fn, void *data, unsigned short priority) {
    (void)priority;
    pthread_mutex_lock(&lock);
    unsigned long handle = 0;
    for (int i = 0; i < 4; i++)
        if (!callbacks[i].active) { callbacks[i].fn = fn; callbacks[i].data = data; callbacks[i].active = 1; handle = (unsigned long)i + 1; break; }
    pthread_mutex_unlock(&lock);
    return handle;
}
void hdUnschedule(unsigned long handle) {
    pthread_mutex_lock(&lock);
    if (handle >= 1 && handle <= 4) callbacks[handle - 1].active = 0;
    pthread_mutex_unlock(&lock);
}
static void *servo_loop(void *arg) {
    (void)arg;
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    for (;;) {
        next.tv_nsec += 1000000;
        if (next.tv_nsec >= 1000000000) { next.tv_nsec -= 1000000000; next.tv_sec++; }
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL);
        pthread_mutex_lock(&lock);
        int run = running, pause = paused;
        pthread_mutex_unlock(&lock);
        if (!run) return NULL;
        if (pause) continue;
        for (int i = 0; i < 4; i++) {
            pthread_mutex_lock(&lock);
            HDSchedulerCallback fn = callbacks[i].active ? callbacks[i].fn : NULL;
            void *data = callbacks[i].data;
            pthread_mutex_unlock(&lock);
            if (fn && fn(data) == 0) hdUnschedule((unsigned long)i + 1);
        }
    }
}
void hdStartScheduler(void) {
    pthread_mutex_lock(&lock);
    int start = !running;
    running = 1;
    pthread_mutex_unlock(&lock);
    if (start) pthread_create(&servo, NULL, servo_loop, NULL);
}
void hdStopScheduler(void) {
    pthread_mutex_lock(&lock);
    int stop = running;
    running = 0;
    pthread_mutex_unlock(&lock);
    if (stop) pthread_join(servo, NULL);
}

/* Test hooks. */
void fake_hd_set_stylus(const double p[3], const double v[3]) {
    pthread_mutex_lock(&lock); memcpy(position, p, sizeof position); memcpy(velocity, v, sizeof velocity); pthread_mutex_unlock(&lock);
}
void fake_hd_set_buttons(int b) { pthread_mutex_lock(&lock); buttons = b; pthread_mutex_unlock(&lock); }
void fake_hd_raise(unsigned code, int internal) {
    pthread_mutex_lock(&lock); pending = (HDErrorInfo){code, internal, 0}; pthread_mutex_unlock(&lock);
}
void fake_hd_pause(int on) { pthread_mutex_lock(&lock); paused = on; pthread_mutex_unlock(&lock); }
/* The force the motors render: zero while force output is off. */
void fake_hd_rendered_force(double out[3]) {
    pthread_mutex_lock(&lock);
    for (int i = 0; i < 3; i++) out[i] = force_output ? force[i] : 0.0;
    pthread_mutex_unlock(&lock);
}
/* bit 0 force output, bit 1 scheduler running, bit 2 device initialised, bit 3 any callback */
int fake_hd_state(void) {
    pthread_mutex_lock(&lock);
    int s = force_output | running << 1 | initialized << 2;
    for (int i = 0; i < 4; i++) if (callbacks[i].active) s |= 8;
    pthread_mutex_unlock(&lock);
    return s;
}
long fake_hd_frames(void) { pthread_mutex_lock(&lock); long f = frames; pthread_mutex_unlock(&lock); return f; }
