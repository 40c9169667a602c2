/* The pin map of the motor on the pins (call 39), for a Raspberry Pi Pico: a brushed DC motor
 * through a two-input H-bridge (DRV8871: IN1, IN2), its two-channel quadrature encoder, two
 * limit switches and a probe input; and the outputs of call 42. Every pin the firmware drives or reads is named here and only here;
 * firmware/README.md draws the wiring. GP numbers are the RP2040's GPIOs (the Pico's pin
 * numbers are in the README). */
#ifndef USBMOTION_PINS_H
#define USBMOTION_PINS_H

/* Encoder channels A and B: two consecutive GPIOs (the PIO state machine reads them as one
 * 2-bit value, A in bit 0), with the chip's pull-ups (open-collector encoders need them). An
 * absolute encoder (call 49 kind 1) gives its PWM output on channel A; B is not read. */
#define PIN_ENCODER_A 2u
#define PIN_ENCODER_B 3u

/* H-bridge inputs: GP6 and GP7 are PWM slice 3's outputs A and B, so both run on one
 * counter at one frequency. */
#define PIN_BRIDGE_IN1 6u
#define PIN_BRIDGE_IN2 7u

/* Enable output: high while the servo runs enabled (a driver's EN or nSLEEP, a relay, a
 * lamp); low otherwise. */
#define PIN_ENABLE 8u

/* Limit switches, each between its pin and GND, with the chip's pull-ups: closed reads low. */
#define PIN_SWITCH_LOWER 10u
#define PIN_SWITCH_UPPER 11u

/* Probe input (call 41), between its pin and GND like the switches, with the chip's pull-up:
 * a touch probe or a plate's contact closes it, and it reads low. */
#define PIN_PROBE 12u

/* The outputs of call 42, on either motor (simulated or on the pins): 0 and 1 digital, high
 * while on (1000); 2 and 3 PWM, high for value per mille of each period. GP16 and GP17 are
 * PWM slice 0's outputs A and B (one counter, one frequency), apart from the bridge's slice
 * 3. A coolant relay's driver, a laser's enable and its power (PWM) input, at 3.3 V. */
#define PIN_OUTPUT_0 13u
#define PIN_OUTPUT_1 14u
#define PIN_OUTPUT_2 16u
#define PIN_OUTPUT_3 17u

/* The outputs' PWM frequency, Hz: the system clock over it must be a multiple of 1000, so
 * that a per mille value is an exact compare level (5 kHz: 25,000 steps, 25 a per mille). */
#ifndef USBMOTION_OUTPUT_PWM_HZ
#define USBMOTION_OUTPUT_PWM_HZ 5000u
#endif

/* A stepper driver's inputs (call 44's drives 1 and 2: an A4988, a DRV8825, a TMC2209 in its
 * step/direction mode), on either motor: STEP (a pulse a step), DIR (high: the steps count
 * up) and EN, which is active low: low while the servo runs enabled on a step drive, high
 * otherwise (the driver's outputs off). */
#define PIN_STEP 18u
#define PIN_DIR 19u
#define PIN_STEP_ENABLE 20u

/* The PIO block and state machine of the encoder input: the quadrature decoder
 * (quadrature.pio, on channels A and B), or with an absolute encoder (call 49 kind 1) the
 * PWM angle reader (pwm_angle.pio, on channel A) in its place. */
#define QUADRATURE_PIO pio0
#define QUADRATURE_SM 0u

/* The step generator (step_dir.pio): its own PIO block (the decoder's program fills most of
 * pio0's instruction memory), the tick clock and the pulse machine. */
#define STEP_PIO pio1
#define STEP_CLOCK_SM 0u
#define STEP_DIR_SM 1u

/* PWM frequency, Hz: above the audible range by default. Configure with
 * -DUSBMOTION_PWM_HZ=...; at the 125 MHz system clock the duty has 125 MHz / f steps. */
#ifndef USBMOTION_PWM_HZ
#define USBMOTION_PWM_HZ 20000u
#endif
#define USBMOTION_PWM_HZ_MIN 1000u   /* the counter's 16 bits: at most 65,536 steps */
#define USBMOTION_PWM_HZ_MAX 200000u /* DRV8871's highest PWM frequency */
_Static_assert(USBMOTION_PWM_HZ >= USBMOTION_PWM_HZ_MIN && USBMOTION_PWM_HZ <= USBMOTION_PWM_HZ_MAX,
               "USBMOTION_PWM_HZ must be within 1000..200000 Hz");

/* Switch debouncing: an edge is taken at once (its count latched then), and the switch is
 * then ignored for this long, microseconds; if it reads otherwise after that, that is its
 * next edge. The probe, read once per servo tick, is debounced the same way over those
 * reads: a change read within this time of its last edge waits until a tick after it. */
#ifndef USBMOTION_SWITCH_DEBOUNCE_US
#define USBMOTION_SWITCH_DEBOUNCE_US 1000u
#endif

#endif
