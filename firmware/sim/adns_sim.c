/* Runs the real downsampler .elf in simavr with a simulated ADNS-3080 on its SPI bus and
 * its UART bridged to a pseudo-terminal, so that the Python serial source can read it.
 *
 *   adns_sim FIRMWARE.elf [options]
 *     --duration S          simulated seconds to run (default 2)
 *     --fps N               sensor frame rate on the simulated clock (default 6400)
 *     --seg T:VX:VY         from T seconds on, move at (VX, VY) inches/s in sensor axes
 *                           (repeatable; before the first segment the sensor stands still)
 *     --absent-until S      no sensor on the bus until S seconds (then it is powered)
 *     --unplug-at S         the sensor disappears at S seconds
 *     --internal-max N      the sensor's internal motion buffer per axis (default 2047)
 *     --absent-miso V       what MISO reads with no sensor (default 0xff)
 *     --squal N             SQUAL while tracking (default 80)
 *     --fast                do not pace the simulation to the wall clock
 *     --wait-start          print the pty, then wait for a line on stdin before running;
 *                           at the end, wait for stdin to close before exiting
 *
 * Prints "PTY <path>" when the pty exists and "SUMMARY <json>" at the end: every count
 * the sensor saw and where it went, the datasheet timing violations, the sensor's
 * registers.  simavr's own chatter goes to stdout too; read only those two lines. */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "avr_ioport.h"
#include "avr_spi.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_irq.h"
#include "sim_time.h"

#include "sensor.h"

#define MAX_SEGS 64
#define MCU_HZ 7372800u

static avr_t *avr;
static sensor_t sensor;
static avr_irq_t *spi_in, *uart_in;

static struct { double t, vx, vy; } segs[MAX_SEGS];
static int nsegs;
static double duration = 2.0, fps = 6400.0, absent_until = -1.0, unplug_at = -1.0;
static int fast, wait_start;
static uint64_t frame_index;
static double frac_x, frac_y;

static int master_fd = -1, slave_fd = -1;
static uint8_t out_buf[1 << 16];
static size_t out_len;
static uint8_t in_buf[1 << 12];
static size_t in_head, in_tail;
static uint64_t uart_tx_bytes, uart_rx_bytes;
static struct timespec wall0;

static uint64_t now_ns(void) { return avr->cycle * 1000000000ull / avr->frequency; }
static avr_cycle_count_t ns_to_cycle(uint64_t ns) { return ns * avr->frequency / 1000000000ull; }

static void die(const char *msg)
{
    fprintf(stderr, "adns_sim: %s: %s\n", msg, strerror(errno));
    exit(2);
}

/* ------------------------------------------------------------------ sensor side */

static void on_spi(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    avr_raise_irq(spi_in, sensor_spi(&sensor, now_ns(), (uint8_t)value));
}

static void on_ncs(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    sensor_ncs(&sensor, now_ns(), (int)value);
}

static void on_reset(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    sensor_reset_pin(&sensor, now_ns(), (int)value);
}

static avr_cycle_count_t on_frame(struct avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a;
    (void)param;
    uint64_t t = now_ns();
    double ts = t / 1e9;
    if (absent_until >= 0 && ts >= absent_until && !sensor.present) {
        sensor_set_present(&sensor, t, 1);
        absent_until = -1;
    }
    if (unplug_at >= 0 && ts >= unplug_at && sensor.present) {
        sensor_set_present(&sensor, t, 0);
        unplug_at = -1;
    }
    double vx = 0, vy = 0;
    for (int i = 0; i < nsegs; i++)
        if (segs[i].t <= ts) {
            vx = segs[i].vx;
            vy = segs[i].vy;
        }
    int cpi = sensor_cpi(&sensor);
    frac_x += vx * cpi / fps;
    frac_y += vy * cpi / fps;
    double ix = floor(frac_x), iy = floor(frac_y);
    frac_x -= ix;
    frac_y -= iy;
    sensor_frame(&sensor, t, (int32_t)ix, (int32_t)iy);
    frame_index++;
    avr_cycle_count_t next = ns_to_cycle((uint64_t)(frame_index * 1e9 / fps));
    return next > when ? next : when + 1;
}

/* ------------------------------------------------------------------ UART <-> pty */

static void on_uart_out(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    if (out_len < sizeof out_buf)
        out_buf[out_len++] = (uint8_t)value;
    uart_tx_bytes++;
}

static void flush_out(void)
{
    size_t off = 0;
    while (off < out_len) {
        ssize_t n = write(master_fd, out_buf + off, out_len - off);
        if (n > 0) {
            off += (size_t)n;
        } else if (n < 0 && errno != EAGAIN && errno != EINTR) {
            die("write pty");
        } else {
            struct pollfd p = {.fd = master_fd, .events = POLLOUT};
            poll(&p, 1, 10);
        }
    }
    out_len = 0;
}

static void pull_in(void)
{
    while (in_head - in_tail < sizeof in_buf) {
        uint8_t tmp[256];
        size_t room = sizeof in_buf - (in_head - in_tail);
        ssize_t n = read(master_fd, tmp, room < sizeof tmp ? room : sizeof tmp);
        if (n <= 0)
            break; /* EAGAIN, or EIO while no one has the slave open */
        for (ssize_t i = 0; i < n; i++)
            in_buf[(in_head++) % sizeof in_buf] = tmp[i];
    }
}

static void pace(void)
{
    if (fast)
        return;
    struct timespec w;
    clock_gettime(CLOCK_MONOTONIC, &w);
    int64_t wall = (int64_t)(w.tv_sec - wall0.tv_sec) * 1000000000ll + (w.tv_nsec - wall0.tv_nsec);
    int64_t ahead = (int64_t)now_ns() - wall;
    if (ahead > 1000000) {
        struct timespec d = {.tv_sec = ahead / 1000000000ll, .tv_nsec = ahead % 1000000000ll};
        nanosleep(&d, NULL);
    }
}

/* Every 100 us of simulated time: one byte to the AVR (115200 baud is 87 us a byte);
 * every 1 ms: exchange with the pty and keep pace with the wall clock. */
static avr_cycle_count_t on_io(struct avr_t *a, avr_cycle_count_t when, void *param)
{
    (void)a;
    (void)param;
    static unsigned ticks;
    if (in_head != in_tail) {
        avr_raise_irq(uart_in, in_buf[(in_tail++) % sizeof in_buf]);
        uart_rx_bytes++;
    }
    if (++ticks % 10 == 0) {
        flush_out();
        pull_in();
        pace();
    }
    return when + avr_usec_to_cycles(avr, 100);
}

static void open_pty(void)
{
    master_fd = posix_openpt(O_RDWR | O_NOCTTY);
    if (master_fd < 0 || grantpt(master_fd) || unlockpt(master_fd))
        die("posix_openpt");
    const char *name = ptsname(master_fd);
    /* keep the slave open ourselves: the line stays up while clients come and go */
    slave_fd = open(name, O_RDWR | O_NOCTTY);
    if (slave_fd < 0)
        die("open pty slave");
    struct termios tio;
    tcgetattr(slave_fd, &tio);
    cfmakeraw(&tio);
    tcsetattr(slave_fd, TCSANOW, &tio);
    fcntl(master_fd, F_SETFL, fcntl(master_fd, F_GETFL) | O_NONBLOCK);
    printf("PTY %s\n", name);
    fflush(stdout);
}

/* ------------------------------------------------------------------ main */

static void nop_sleep(avr_t *a, avr_cycle_count_t howlong)
{
    (void)a;
    (void)howlong; /* never sleep in wall-clock time: pace() does the pacing */
}

static void summary(void)
{
    printf("SUMMARY {\"sim_s\": %.6f, \"gen\": [%lld, %lld], \"read\": [%lld, %lld], "
           "\"buffered\": [%lld, %lld], \"lost\": [%lld, %lld], \"cleared\": [%lld, %lld], "
           "\"untracked\": [%lld, %lld], \"frames\": %u, \"bursts\": %u, \"reads\": %u, "
           "\"ovf_reads\": %u, \"resets\": %u, \"spi_bytes\": %u, \"config\": %u, \"cpi\": %d, "
           "\"violations\": %u, \"first_violation\": \"%s\", \"uart_tx_bytes\": %llu, "
           "\"uart_rx_bytes\": %llu}\n",
           now_ns() / 1e9, (long long)sensor.gen_x, (long long)sensor.gen_y,
           (long long)sensor.read_x, (long long)sensor.read_y, (long long)sensor.buf_x,
           (long long)sensor.buf_y, (long long)sensor.lost_x, (long long)sensor.lost_y,
           (long long)sensor.cleared_x, (long long)sensor.cleared_y,
           (long long)sensor.untracked_x, (long long)sensor.untracked_y, sensor.frames,
           sensor.bursts, sensor.reads, sensor.ovf_reads, sensor.resets, sensor.spi_bytes,
           sensor.config, sensor_cpi(&sensor), sensor.violations, sensor.first_violation,
           (unsigned long long)uart_tx_bytes, (unsigned long long)uart_rx_bytes);
    fflush(stdout);
}

static double num(const char *s, const char *what)
{
    char *end;
    double v = strtod(s, &end);
    if (*s == 0 || *end != 0) {
        fprintf(stderr, "adns_sim: %s: not a number: %s\n", what, s);
        exit(2);
    }
    return v;
}

static const char USAGE[] =
    "usage: adns_sim FIRMWARE.elf [options]\n"
    "  --duration S          simulated seconds to run (default 2)\n"
    "  --fps N               sensor frame rate on the simulated clock (default 6400)\n"
    "  --seg T:VX:VY         from T seconds on, move at (VX, VY) inches/s in sensor axes\n"
    "                        (repeatable; before the first segment the sensor stands still)\n"
    "  --absent-until S      no sensor on the bus until S seconds (then it is powered)\n"
    "  --unplug-at S         the sensor disappears at S seconds\n"
    "  --internal-max N      the sensor's internal motion buffer per axis (default 2047)\n"
    "  --absent-miso V       what MISO reads with no sensor (default 0xff)\n"
    "  --squal N             SQUAL while tracking (default 80)\n"
    "  --fast                do not pace the simulation to the wall clock\n"
    "  --wait-start          print the pty, then wait for a line on stdin before running;\n"
    "                        at the end, wait for stdin to close before exiting\n"
    "Prints \"PTY <path>\" when the pty exists and \"SUMMARY <json>\" at the end.\n";

int main(int argc, char **argv)
{
    if (argc >= 2 && (!strcmp(argv[1], "-h") || !strcmp(argv[1], "--help"))) {
        fputs(USAGE, stdout);
        return 0;
    }
    if (argc < 2) {
        fputs(USAGE, stderr);
        return 2;
    }
    const char *elf = argv[1];
    int present = 1;
    sensor_init(&sensor, 1);
    for (int i = 2; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--fast")) { fast = 1; continue; }
        if (!strcmp(a, "--wait-start")) { wait_start = 1; continue; }
        if (!v) { fprintf(stderr, "adns_sim: %s needs a value\n", a); return 2; }
        i++;
        if (!strcmp(a, "--duration")) duration = num(v, a);
        else if (!strcmp(a, "--fps")) fps = num(v, a);
        else if (!strcmp(a, "--absent-until")) { absent_until = num(v, a); present = 0; }
        else if (!strcmp(a, "--unplug-at")) unplug_at = num(v, a);
        else if (!strcmp(a, "--internal-max")) sensor.internal_max = (int64_t)num(v, a);
        else if (!strcmp(a, "--absent-miso")) sensor.absent_miso = (uint8_t)strtol(v, NULL, 0);
        else if (!strcmp(a, "--squal")) sensor.squal = (uint8_t)num(v, a);
        else if (!strcmp(a, "--seg")) {
            if (nsegs == MAX_SEGS || sscanf(v, "%lf:%lf:%lf", &segs[nsegs].t, &segs[nsegs].vx,
                                            &segs[nsegs].vy) != 3) {
                fprintf(stderr, "adns_sim: --seg wants T:VX:VY, got %s\n", v);
                return 2;
            }
            nsegs++;
        } else {
            fprintf(stderr, "adns_sim: unknown option %s\n", a);
            return 2;
        }
    }
    sensor.present = present;

    elf_firmware_t f;
    memset(&f, 0, sizeof f);
    if (elf_read_firmware(elf, &f) != 0) {
        fprintf(stderr, "adns_sim: cannot read %s\n", elf);
        return 2;
    }
    if (!f.mmcu[0])
        strcpy(f.mmcu, "atmega8");
    if (!f.frequency)
        f.frequency = MCU_HZ;
    avr = avr_make_mcu_by_name(f.mmcu);
    if (!avr) {
        fprintf(stderr, "adns_sim: simavr does not know %s\n", f.mmcu);
        return 2;
    }
    avr_init(avr);
    avr_load_firmware(avr, &f);
    avr->sleep = nop_sleep;

    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~AVR_UART_FLAG_STDIO;
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            on_uart_out, NULL);
    uart_in = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_SPI_GETIRQ(0), SPI_IRQ_OUTPUT), on_spi,
                            NULL);
    spi_in = avr_io_getirq(avr, AVR_IOCTL_SPI_GETIRQ(0), SPI_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 2), on_ncs, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 1), on_reset, NULL);

    open_pty();
    if (wait_start) {
        char line[64];
        if (!fgets(line, sizeof line, stdin))
            return 0;
    }
    clock_gettime(CLOCK_MONOTONIC, &wall0);
    avr_cycle_timer_register(avr, ns_to_cycle((uint64_t)(1e9 / fps)), on_frame, NULL);
    avr_cycle_timer_register_usec(avr, 1000, on_io, NULL);

    uint64_t end = (uint64_t)(duration * 1e9);
    while (now_ns() < end) {
        int st = avr_run(avr);
        if (st == cpu_Done || st == cpu_Crashed) {
            fprintf(stderr, "adns_sim: the AVR stopped (state %d) at %.6f s\n", st,
                    now_ns() / 1e9);
            break;
        }
    }
    flush_out();
    summary();
    if (wait_start) {
        char line[64];
        while (fgets(line, sizeof line, stdin)) {
        }
    }
    return 0;
}
