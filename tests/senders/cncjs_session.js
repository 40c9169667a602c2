// Drives a running cncjs server through its Socket.IO API, as its web page does: open the
// port as a Grbl controller, unlock, home, jog, load and start a program, hold and resume
// it, wait for its end. Prints one JSON line with what it saw, and its log: what cncjs
// wrote and read outside the program's stream, the states and positions it reported.
//
// usage: node cncjs_session.js CNCJS_URL PORT_PATH PROGRAM_FILE
// environment: JOG, the jog line (by default 20 mm along X and -10 mm along Y);
// UNLOCKED=message, after $X wait for grbl's "[MSG:Caution: Unlocked]" rather than Idle
'use strict';

const fs = require('fs');
const { signin } = require('./cncjs_signin');
const io = require('socket.io-client');

const [url, portPath, programFile] = process.argv.slice(2);
const program = fs.readFileSync(programFile, 'utf8');
const STEP_TIMEOUT_MS = 15000;
const HOMING_TIMEOUT_MS = 60000;
const JOG = process.env.JOG || '$J=G91 G21 X20 Y-10 F1200'; // 1.1 s: seen in the reports

async function main() {
  const token = await signin(url);
  const socket = io.connect(url, { query: `token=${token}` });
  const seen = { states: [], reads: [], alarms: [], errors: [], sender: null, workflow: [] };
  const log = [];
  const note = (text) => log.push([Date.now(), text]);
  let lastReport = '';
  let status = {};
  let senderStatus = {};
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
        + ` (state ${status.activeState}, last reads ${seen.reads.slice(-5).join(' | ')})`));
    }, timeoutMs);
    waiters.push({ condition, resolve, timer });
  });
  const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));
  const command = (...args) => socket.emit('command', portPath, ...args);

  socket.on('connect', () => check());
  socket.on('connect_error', (error) => { seen.errors.push(`connect_error: ${error}`); });
  socket.on('controller:state', (type, state) => {
    status = state.status || {};
    const mpos = status.mpos || {};
    const report = `${status.activeState}${status.subState >= 0 ? `:${status.subState}` : ''}`
      + ` MPos ${mpos.x},${mpos.y},${mpos.z}`;
    if (report !== lastReport) note(`status ${report}`);
    lastReport = report;
    const last = seen.states[seen.states.length - 1];
    if (status.activeState && status.activeState !== last) {
      seen.states.push(status.activeState);
    }
    check();
  });
  socket.on('serialport:write', (data) => { note(`wrote ${JSON.stringify(data)}`); });
  socket.on('serialport:read', (line) => {
    seen.reads.push(line);
    note(`read ${JSON.stringify(line)}`);
    if (line.startsWith('ALARM:')) seen.alarms.push(line);
    if (line.startsWith('error:')) seen.errors.push(line);
    check();
  });
  socket.on('sender:status', (data) => { senderStatus = data; check(); });
  socket.on('workflow:state', (state) => {
    seen.workflow.push(state);
    note(`workflow ${state}`);
    check();
  });

  await until('the Socket.IO connection', () => socket.connected);
  await new Promise((resolve, reject) => {
    socket.emit('open', portPath, { controllerType: 'Grbl', baudrate: 115200 }, (error) => {
      if (error) reject(new Error(`cncjs could not open ${portPath}: ${error}`)); else resolve();
    });
  });
  await until('the Grbl banner', () => seen.reads.some((line) => line.startsWith('Grbl 1.1h')));
  await until('a status report', () => Boolean(status.activeState));

  command('unlock');
  if (process.env.UNLOCKED === 'message') {
    await until('the unlock message', () => seen.reads.includes('[MSG:Caution: Unlocked]'));
  } else {
    await until('Idle after $X', () => status.activeState === 'Idle');
  }
  command('homing');
  await until('homing', () => seen.states.includes('Home'));
  // Homing is machine time (a few seconds here; a real machine's take longer): on a host
  // loaded beyond its cores the simulated devices stand still while it computes.
  await until('Idle after homing', () => status.activeState === 'Idle', HOMING_TIMEOUT_MS);

  command('gcode', JOG);
  await until('the jog', () => seen.states.includes('Jog'));
  await until('Idle after the jog', () => status.activeState === 'Idle');
  const afterJog = { ...status.mpos };

  await new Promise((resolve, reject) => {
    command('gcode:load', 'square.nc', program, {}, (error) => {
      if (error) reject(error); else resolve();
    });
  });
  note('gcode:start');
  command('gcode:start');
  await until('Run', () => status.activeState === 'Run');
  await sleep(300);
  note('gcode:pause');
  command('gcode:pause');
  await until('Hold:0', () => status.activeState === 'Hold' && status.subState === 0);
  const held = { ...status.mpos };
  await sleep(300);
  const stillHeld = { ...status.mpos };
  note('gcode:resume');
  command('gcode:resume');
  await until('Run after resume', () => status.activeState === 'Run');
  await until('the program end', () => senderStatus.total > 0
    && senderStatus.received === senderStatus.total && status.activeState === 'Idle');
  await until('the workflow idle', () => seen.workflow[seen.workflow.length - 1] === 'idle');
  seen.sender = { total: senderStatus.total, sent: senderStatus.sent,
    received: senderStatus.received };

  socket.emit('close', portPath);
  await sleep(200);
  socket.close();
  process.stdout.write(`${JSON.stringify({
    ...seen, reads: seen.reads.length, afterJog, held, stillHeld, final: status.mpos, log,
  })}\n`);
}

main().then(() => process.exit(0), (error) => {
  process.stderr.write(`${error.stack || error}\n`);
  process.exit(1);
});
