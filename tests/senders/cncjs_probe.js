// cncjs's probe widget against a running cncjs server, through its Socket.IO API: open the
// port as a Grbl controller, unlock, home, then the widget's Z probe as it sends it (one
// "gcode" command of its lines: relative, G38.2 down at the probe feed, absolute, G10 L20
// putting the touch plate's height on the contact, relative, the retraction, absolute), and
// wait until every line is answered. Prints one JSON line: the lines cncjs read (the probe's
// [PRB:...] among them), alarms and errors, the machine position at the end.
//
// usage: node cncjs_probe.js CNCJS_URL PORT_PATH
// environment: PROBE_LINES, the widget's lines joined by newlines
'use strict';

const { signin } = require('./cncjs_signin');
const io = require('socket.io-client');

const [url, portPath] = process.argv.slice(2);
const LINES = process.env.PROBE_LINES.split('\n');
const STEP_TIMEOUT_MS = 30000;
const HOMING_TIMEOUT_MS = 60000;

async function main() {
  const token = await signin(url);
  const socket = io.connect(url, { query: `token=${token}` });
  const reads = [];
  const alarms = [];
  const errors = [];
  let status = {};
  const waiters = [];
  const check = () => {
    for (const waiter of waiters.slice()) {
      if (waiter.condition()) {
        waiters.splice(waiters.indexOf(waiter), 1);
        clearTimeout(waiter.timer);
        waiter.resolve();
      }
    }
  };
  const until = (what, condition, timeoutMs = STEP_TIMEOUT_MS) => new Promise((resolve, reject) => {
    if (condition()) { resolve(); return; }
    const timer = setTimeout(() => {
      reject(new Error(`cncjs: ${what} did not happen within ${timeoutMs} ms`
        + ` (state ${status.activeState}, last reads ${reads.slice(-6).join(' | ')})`));
    }, timeoutMs);
    waiters.push({ condition, resolve, timer });
  });
  const command = (...args) => socket.emit('command', portPath, ...args);

  socket.on('connect', () => check());
  socket.on('connect_error', (error) => { errors.push(`connect_error: ${error}`); });
  socket.on('controller:state', (type, state) => { status = state.status || {}; check(); });
  socket.on('serialport:read', (line) => {
    reads.push(line);
    if (line.startsWith('ALARM:')) alarms.push(line);
    if (line.startsWith('error:')) errors.push(line);
    check();
  });

  await until('the Socket.IO connection', () => socket.connected);
  await new Promise((resolve, reject) => {
    socket.emit('open', portPath, { controllerType: 'Grbl', baudrate: 115200 }, (error) => {
      if (error) reject(new Error(`cncjs could not open ${portPath}: ${error}`)); else resolve();
    });
  });
  await until('the Grbl banner', () => reads.some((line) => line.startsWith('Grbl 1.1h')));
  await until('a status report', () => Boolean(status.activeState));
  command('unlock');
  await until('Idle after $X', () => status.activeState === 'Idle');
  command('homing');
  await until('homing', () => status.activeState === 'Home');
  await until('Idle after homing', () => status.activeState === 'Idle', HOMING_TIMEOUT_MS);

  const before = reads.filter((line) => line === 'ok').length;
  command('gcode', LINES.join('\n'));
  await until(`the ${LINES.length} lines answered`,
    () => reads.filter((line) => line === 'ok').length >= before + LINES.length
      || alarms.length > 0 || errors.length > 0);
  await until('Idle after the probe', () => status.activeState === 'Idle');
  socket.emit('close', portPath);
  await new Promise((resolve) => setTimeout(resolve, 200));
  socket.close();
  process.stdout.write(`${JSON.stringify({ reads, alarms, errors, final: status.mpos })}\n`);
}

main().then(() => process.exit(0), (error) => {
  process.stderr.write(`${error.stack || error}\n`);
  process.exit(1);
});
