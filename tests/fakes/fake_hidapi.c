/* A stand-in for libhidapi-hidraw.so.0, put first on LD_LIBRARY_PATH of a child process
 * so nanoforce's real hidapi FFI path runs against it. One device, with the ids in
 * $FAKE_HID_VID and $FAKE_HID_PID (hex). Each hid_read_timeout returns the next input
 * report from $FAKE_HID_REPORTS (a file of hex lines, one report per line; a line
 * "-" is a read with nothing pending); after the last one, reads return nothing, or
 * fail as an unplugged device if $FAKE_HID_UNPLUG is set. Output reports and calls are
 * logged to $FAKE_HID_LOG. */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <wchar.h>

#define FAKE_LOG_ENV "FAKE_HID_LOG"
#include "fake_log.h"

struct hid_device_info {
    char *path;
    unsigned short vendor_id, product_id;
    wchar_t *serial_number;
    unsigned short release_number;
    wchar_t *manufacturer_string, *product_string;
    unsigned short usage_page, usage;
    int interface_number;
    struct hid_device_info *next;
    int bus_type;
};
typedef struct { FILE *reports; int unplugged; } hid_device;

static hid_device the_device;
static const wchar_t *last_error = L"";

static unsigned short env_id(const char *name) {
    const char *v = getenv(name);
    return v ? (unsigned short)strtoul(v, NULL, 16) : 0;
}

int hid_init(void) { return 0; }
int hid_exit(void) { return 0; }

struct hid_device_info *hid_enumerate(unsigned short vid, unsigned short pid) {
    (void)vid; (void)pid;
    struct hid_device_info *d = calloc(1, sizeof *d);
    d->path = strdup("/dev/hidraw7");
    d->vendor_id = env_id("FAKE_HID_VID");
    d->product_id = env_id("FAKE_HID_PID");
    d->product_string = wcsdup(L"Fake Joystick");
    return d;
}
void hid_free_enumeration(struct hid_device_info *d) {
    while (d) { struct hid_device_info *n = d->next; free(d->path); free(d->product_string); free(d); d = n; }
}

hid_device *hid_open(unsigned short vid, unsigned short pid, const wchar_t *serial) {
    (void)serial;
    logf_("open %04x:%04x", vid, pid);
    if (vid != env_id("FAKE_HID_VID") || pid != env_id("FAKE_HID_PID")) {
        last_error = L"No HID device with the requested vendor and product id";
        return NULL;
    }
    const char *path = getenv("FAKE_HID_REPORTS");
    the_device.reports = path ? fopen(path, "r") : NULL;
    the_device.unplugged = 0;
    return &the_device;
}

int hid_read_timeout(hid_device *dev, unsigned char *data, size_t length, int ms) {
    (void)ms;
    char line[1024];
    if (dev->unplugged) { last_error = L"Input/output error (device unplugged)"; return -1; }
    if (!dev->reports || !fgets(line, sizeof line, dev->reports)) {
        if (getenv("FAKE_HID_UNPLUG")) { dev->unplugged = 1; last_error = L"Input/output error (device unplugged)"; return -1; }
        return 0;
    }
    if (line[0] == '-') return 0;
    size_t n = 0;
    char *p = line;
    while (n < length) {
        char *end;
        unsigned long b = strtoul(p, &end, 16);
        if (end == p) break;
        data[n++] = (unsigned char)b;
        p = end;
    }
    return (int)n;
}

int hid_write(hid_device *dev, const unsigned char *data, size_t length) {
    (void)dev;
    char text[3 * 256 + 8] = "write";
    for (size_t i = 0; i < length && i < 256; i++) sprintf(text + strlen(text), " %02x", data[i]);
    logf_("%s", text);
    return (int)length;
}

const wchar_t *hid_error(hid_device *dev) { (void)dev; return last_error; }

void hid_close(hid_device *dev) {
    if (dev->reports) fclose(dev->reports);
    dev->reports = NULL;
    logf_("close");
}
