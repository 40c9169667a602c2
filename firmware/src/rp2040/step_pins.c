/* The step/direction outputs of call 44's drives 1 and 2 (platform.h): STEP and DIR from a
 * PIO step generator, and the driver's enable (pins.h has the pins), on either motor.
 *
 * step_dir.pio (assembled by the SDK's pioasm at build time) has the two state machines and
 * how their cycles add up: step_clock raises a PIO flag at the start of every tick's frame,
 * step_dir plays a frame per tick from its TX FIFO. A tick with N steps is one frame: DIR,
 * then the set-up, then N pulses of `pulse` cycles high, spread over the tick's room
 * (T - setup) in whole step-clock periods: with s = room / N rounded down and the rest r,
 * the first r - 4 steps s + 1 apart and the others s apart (r under 5: all s apart), the
 * last pulse ending at least a pulse before the next tick's first rise.
 *
 * The tick's start: step_clock is (re)started first thing in the servo alarm's interrupt
 * (step_pins_tick, before the device's tick) when the period changes; its flag
 * then rises 33 cycles after that instant and every period after it. core1 pushes the
 * tick's frame from platform_steps_issue, later in the same tick: the frame plays from the
 * next tick's start on, whatever the tick's own computation takes (up to a whole period).
 * A frame that finds no room in the FIFO (only after two late ticks in a row) is not
 * dropped: its steps are carried into the next tick's frame (while the driver is enabled:
 * one that is off takes none). */
#include <stdbool.h>
#include <stdint.h>

#include "hardware/gpio.h"
#include "hardware/pio.h"
#include "hardware/structs/sio.h"
#include "hardware/sync.h"
#include "pico/platform.h"

#include "pins.h"
#include "platform.h"
#include "rp2040_platform.h"
#include "step_dir.pio.h"

#define FIFO_WORDS 8u                /* the TX FIFO joined with the RX one */
#define FRAME_MOST_WORDS 6u          /* a wide tick's four and run 2's two */
#define RUN_SWITCH_CYCLES 5u         /* what run 2's first gap takes beyond its spacing */
#define NARROW_MAX 65537u            /* pulse and set-up packed in one word up to this */
#define STEP_ENABLE_MASK (1u << PIN_STEP_ENABLE)
#define MIN_PULSE_CYCLES 13u         /* 100 ns: call 46's least pulse */
#define MIN_SETUP_CYCLES 2u          /* what step_dir needs between DIR and the first rise */

/* The timing of calls 5 and 46, from core0 to core1: core0 writes it between two increments
 * of its sequence (odd while it writes); core1 copies it at the start of a tick when the
 * sequence is even and has changed (step_pins_tick), and keeps it when the sequence did not
 * move meanwhile. */
typedef struct {
    uint32_t pulse;    /* step-clock periods high */
    uint32_t setup;    /* periods from DIR to the first rise */
    uint32_t tick;     /* periods per servo tick */
} step_timing_t;

static step_timing_t staged;
volatile uint32_t step_timing_staged; /* the sequence */
uint32_t step_timing_taken;           /* the sequence core1 took (rp2040_platform.h) */

/* core1's own: the timing in force and what it gives a frame. */
typedef struct {
    uint32_t tick;         /* the period step_clock runs at, 0 before it first runs */
    uint32_t room;         /* T - setup: the periods a tick's steps are spread over */
    uint32_t most;         /* the most steps a frame takes: room / (2 x pulse) */
    uint32_t head;         /* the first word's address part: tick_narrow or tick_wide */
    uint32_t timing_words[2];  /* narrow: the packed pulse and set-up (one); wide: both */
    uint32_t timing_count;
    uint32_t low_base;     /* pulse + 4: a run's spacing less this is its low loop's count */
    int32_t carry;         /* steps a full FIFO held back, for the next frame */
} step_frames_t;

static step_frames_t frames;
static bool started;
static uint clock_offset;  /* where the programs sit in the PIO's instruction memory */
static uint dir_offset;

void platform_steps_start(void) {
    PIO pio = STEP_PIO;
    gpio_init(PIN_STEP_ENABLE);
    gpio_put(PIN_STEP_ENABLE, true); /* active low: the driver off */
    gpio_set_dir(PIN_STEP_ENABLE, GPIO_OUT);

    clock_offset = pio_add_program(pio, &step_clock_program);
    pio_sm_config clock = step_clock_program_get_default_config(clock_offset);
    sm_config_set_out_shift(&clock, true, false, 32);
    sm_config_set_clkdiv_int_frac(&clock, 1, 0);
    pio_sm_init(pio, STEP_CLOCK_SM, clock_offset + step_clock_offset_count, &clock);

    dir_offset = pio_add_program(pio, &step_dir_program);
    pio_sm_config dir = step_dir_program_get_default_config(dir_offset);
    sm_config_set_sideset_pins(&dir, PIN_STEP);
    sm_config_set_out_pins(&dir, PIN_DIR, 1);
    sm_config_set_out_shift(&dir, true, false, 32); /* right: `out pins, 1` takes bit 0 */
    sm_config_set_fifo_join(&dir, PIO_FIFO_JOIN_TX);
    sm_config_set_clkdiv_int_frac(&dir, 1, 0);
    pio_sm_set_pins_with_mask(pio, STEP_DIR_SM, 0u, (1u << PIN_STEP) | (1u << PIN_DIR));
    pio_sm_set_pindirs_with_mask(pio, STEP_DIR_SM, (1u << PIN_STEP) | (1u << PIN_DIR),
                                 (1u << PIN_STEP) | (1u << PIN_DIR));
    pio_gpio_init(pio, PIN_STEP);
    pio_gpio_init(pio, PIN_DIR);
    pio_sm_init(pio, STEP_DIR_SM, dir_offset + step_dir_offset_frame, &dir);
    pio_sm_set_enabled(pio, STEP_DIR_SM, true); /* waits for its first frame */
    started = true;
}

void platform_steps_timing(uint32_t pulse_cycles, uint32_t setup_cycles, uint32_t tick_cycles) {
    uint32_t sequence = step_timing_staged;
    step_timing_staged = sequence + 1u;
    __dmb();
    staged.pulse = pulse_cycles;
    staged.setup = setup_cycles;
    staged.tick = tick_cycles;
    __dmb();
    step_timing_staged = sequence + 2u;
}

/* core1: the staged timing in force from this tick on; step_clock restarted now when the
 * period changed (or it never ran), so its frames start at this tick's offset. */
void __not_in_flash_func(step_pins_take_timing)(void) {
    uint32_t sequence = step_timing_staged;
    if ((sequence & 1u) != 0 || !started) {
        return; /* being written: taken next tick */
    }
    __dmb();
    step_timing_t timing = staged;
    __dmb();
    if (step_timing_staged != sequence || timing.pulse < MIN_PULSE_CYCLES ||
        timing.tick <= timing.setup) {
        return; /* written meanwhile (taken next tick), or not a timing a frame can play */
    }
    step_timing_taken = sequence;
    uint32_t setup = timing.setup < MIN_SETUP_CYCLES ? MIN_SETUP_CYCLES : timing.setup;
    frames.room = timing.tick - timing.setup;
    frames.most = frames.room / (2u * timing.pulse);
    if (timing.pulse <= NARROW_MAX && setup <= NARROW_MAX) {
        frames.head = dir_offset + step_dir_offset_tick_narrow;
        frames.timing_words[0] = (timing.pulse - 2u) | (setup - 2u) << 16;
        frames.timing_count = 1;
    } else {
        frames.head = dir_offset + step_dir_offset_tick_wide;
        frames.timing_words[0] = timing.pulse - 2u;
        frames.timing_words[1] = setup - 2u;
        frames.timing_count = 2;
    }
    frames.low_base = timing.pulse + 4u;
    if (timing.tick != frames.tick) {
        /* step_clock from its loop: X = T - 3, its first flag 33 cycles after this */
        PIO pio = STEP_PIO;
        pio_sm_set_enabled(pio, STEP_CLOCK_SM, false);
        pio_sm_clear_fifos(pio, STEP_CLOCK_SM);
        pio_sm_restart(pio, STEP_CLOCK_SM);
        pio_sm_put(pio, STEP_CLOCK_SM, timing.tick - 3u);
        pio_sm_exec(pio, STEP_CLOCK_SM, pio_encode_pull(false, true));
        pio_sm_exec(pio, STEP_CLOCK_SM, pio_encode_mov(pio_x, pio_osr));
        pio_sm_exec(pio, STEP_CLOCK_SM, pio_encode_set(pio_y, 31));
        pio_sm_exec(pio, STEP_CLOCK_SM, pio_encode_jmp(clock_offset + step_clock_offset_count));
        pio_sm_set_enabled(pio, STEP_CLOCK_SM, true);
        frames.tick = timing.tick;
    }
}

void __not_in_flash_func(platform_steps_issue)(int32_t steps, bool enable) {
    if (enable) {
        sio_hw->gpio_clr = STEP_ENABLE_MASK; /* active low: the driver on */
    } else {
        sio_hw->gpio_set = STEP_ENABLE_MASK;
    }
    if (!enable) {
        frames.carry = 0; /* a driver that is off takes no steps */
    }
    int32_t total = steps + frames.carry;
    if (total == 0) {
        frames.carry = 0;
        return;
    }
    uint32_t count = total < 0 ? 0u - (uint32_t)total : (uint32_t)total;
    if (count > frames.most) {
        count = frames.most; /* only when the timing just changed or steps were carried */
    }
    PIO pio = STEP_PIO;
    if (count == 0 || pio_sm_get_tx_fifo_level(pio, STEP_DIR_SM) > FIFO_WORDS - FRAME_MOST_WORDS) {
        frames.carry = total;
        return;
    }
    frames.carry = total < 0 ? total + (int32_t)count : total - (int32_t)count;
    /* the core's divider in place (as sci_udiv): the tick interrupts only core1's idle loop */
    sio_hw->div_udividend = frames.room;
    sio_hw->div_udivisor = count;
    while ((sio_hw->div_csr & SIO_DIV_CSR_READY_BITS) == 0) {
    }
    uint32_t rest = sio_hw->div_remainder;
    uint32_t spacing = sio_hw->div_quotient;
    /* run 1: the steps s + 1 apart, r - 4 of them (the switch to run 2 takes the other 4 and
     * run 2's first gap s); or all of them s apart */
    uint32_t longer = rest >= RUN_SWITCH_CYCLES ? rest - (RUN_SWITCH_CYCLES - 1u) : 0u;
    uint32_t first = longer != 0 ? longer : count;
    uint32_t low = spacing - frames.low_base;
    io_wo_32 *fifo = &pio->txf[STEP_DIR_SM];
    *fifo = frames.head | (first - 1u) << 5;
    *fifo = frames.timing_words[0];
    if (frames.timing_count == 2) {
        *fifo = frames.timing_words[1];
    }
    if (longer == 0) {
        *fifo = low << 1 | (total > 0 ? 1u : 0u);
        return;
    }
    *fifo = (low + 1u) << 1 | (total > 0 ? 1u : 0u);
    *fifo = (dir_offset + step_dir_offset_run) | (count - longer) << 5;
    *fifo = low;
}
