// The usbmotion dashboard: the server's live model shown, and its controls.
//
// GET /api/state at load, then the WebSocket /api/live's pushes (50 a second and more) drive
// every panel; the program and its toolpath are fetched again whenever its revision changes.

import { Api, Live, takeToken } from './api.js';
import { ErrorCharts } from './charts.js';
import { Controls } from './controls.js';
import { DevicesPanel } from './devices.js';
import { Readout } from './dro.js';
import { byId, el, setText } from './format.js';
import { MessageLog } from './log.js';
import { PredictionPanel } from './prediction.js';
import { ProgramText } from './program.js';
import { ToolpathView, webglAvailable } from './toolpath.js';
import { TuningPanel } from './tuning.js';

// What a test (tests/web/dashboard_page.js) reads: the time of every chart redraw
// (performance.now(), ms), the number of pushes, and the last state.
const CHART_UPDATES_KEPT = 20000;
const exposed = { chartUpdates: [], pushes: 0, state: null };
window.usbmotionDashboard = exposed;

const PROGRAM_STATES = new Set(['Run', 'Hold', 'Paused']);

const token = takeToken();
const api = new Api(token);
const log = new MessageLog();
const readout = new Readout();
const programText = new ProgramText();
const charts = new ErrorCharts(byId('charts'), {
  onDraw: (timeMs) => {
    exposed.chartUpdates.push(timeMs);
    if (exposed.chartUpdates.length > CHART_UPDATES_KEPT) {
      exposed.chartUpdates.splice(0, exposed.chartUpdates.length - CHART_UPDATES_KEPT);
    }
  },
});
const toolpathBox = byId('toolpath');
let toolpath = null;
if (webglAvailable()) {
  toolpath = new ToolpathView(toolpathBox);
} else {
  toolpathBox.append(el('p', { class: 'no-webgl' },
    'The toolpath needs WebGL, which this browser has turned off.'));
}
const controls = new Controls(api, log, {
  onProgramOpened: (program) => {
    prediction.clear();
    showProgram(program);
  },
});
const prediction = new PredictionPanel(api, log, programText, { fromLine: byId('from-line') });
const tuning = new TuningPanel(api, log);
new DevicesPanel(api, log);

const alarmBanner = byId('alarm-banner');
const alarmText = byId('alarm-text');
const alarmHelp = byId('alarm-help');
const downBanner = byId('disconnected');
const connection = byId('connection');
const machineName = byId('machine-name');

let shownRevision = null;
let shownName = null;
let shownHadPath = false;
let programFetch = null;
let previousState = null;
let workOriginKey = '';
let trailRevision = null;

function showProgram(program) {
  const name = program ? program.name : null;
  const hasPath = Boolean(program && program.toolpath);
  // Framed anew for another program, or for the first plan of this one (an opened
  // program's plan comes in a later revision).
  const refit = name !== shownName || (hasPath && !shownHadPath);
  shownName = name;
  shownHadPath = hasPath;
  shownRevision = program ? program.revision : null;
  controls.programProblem = { revision: shownRevision, text: program ? program.problem : '' };
  programText.setProgram(program);
  if (toolpath) {
    toolpath.setProgram(program ? program.toolpath : null, { refit });
  }
}

// The program fetched again until what came matches the latest revision the state named.
async function refreshProgram() {
  if (programFetch) {
    return;
  }
  programFetch = (async () => {
    try {
      for (let tries = 0; tries < 5; tries += 1) {
        const wanted = exposed.state && exposed.state.program;
        if (!wanted) {
          showProgram(null);
          return;
        }
        if (wanted.revision === shownRevision) {
          return;
        }
        showProgram(await api.get('program'));
      }
    } catch (error) {
      log.error(`Program: ${error.message}`);
    } finally {
      programFetch = null;
    }
  })();
}

function showState(state, { push }) {
  exposed.state = state;
  setText(machineName, state.machine || '');
  readout.show(state);
  controls.update(state);
  prediction.update(state);
  tuning.update(state);
  if (push) {
    exposed.pushes += 1;
    charts.push(state);
  }

  const alarmed = Boolean(state.alarm) || state.state === 'Alarm';
  alarmBanner.hidden = !alarmed;
  setText(alarmText, state.alarm || 'the machine is in Alarm');
  setText(alarmHelp, state.alarm_help || '');

  const program = state.program;
  if ((program ? program.revision : null) !== shownRevision) {
    refreshProgram();
  }
  const line = program ? program.line : 0;
  programText.setCurrent(line);
  programText.showProgress(program);
  // A program that left Run, Hold or Paused before its end: its line is where to resume.
  const was = previousState ? previousState.state : 'Idle';
  if (PROGRAM_STATES.has(was) && !PROGRAM_STATES.has(state.state) && program
      && program.lines_done < program.lines_total && line > 0) {
    controls.offerResume(line);
  }

  if (toolpath) {
    // A new run starts a new executed path. The server plans the program again as a run
    // starts (a new revision) and its first push already counts the lines before the first
    // move as done, so a run is told by the revision; an MDI line, which goes to Run too,
    // keeps the path.
    const before = previousState ? previousState.state : 'Idle';
    if (state.state === 'Run' && !PROGRAM_STATES.has(before) && program
        && (program.lines_done === 0 || program.revision !== trailRevision)) {
      trailRevision = program.revision;
      toolpath.clearTrail();
    }
    toolpath.setLine(line);
    toolpath.addPosition(state, { record: push && state.state !== 'Homing' });
    const originKey = JSON.stringify(state.work_offset_mm);
    if (originKey !== workOriginKey) {
      workOriginKey = originKey;
      toolpath.setWorkOrigin(state.work_offset_mm);
    }
  }
  previousState = state;
}

async function loadState() {
  try {
    showState(await api.get('state'), { push: false });
  } catch (error) {
    log.error(`State: ${error.message}`);
  }
}

const live = new Live(api, {
  onOpen: (reconnected) => {
    downBanner.hidden = true;
    controls.setConnected(true);
    prediction.setConnected(true);
    document.body.classList.remove('offline');
    setText(connection, 'live');
    connection.classList.remove('connection-down');
    if (reconnected) {
      loadState();
    }
  },
  onData: (data) => {
    if (data.type === 'state') {
      showState(data, { push: true });
    } else if (data.type === 'message') {
      log.message(data);
    }
  },
  onDown: () => {
    downBanner.hidden = false;
    controls.setConnected(false);
    prediction.setConnected(false);
    document.body.classList.add('offline');
    setText(connection, 'disconnected');
    connection.classList.add('connection-down');
  },
});

if (!token) {
  log.error('This address has no token: open the address usbmotion web printed (it ends in ?token=…).');
}
byId('view-top').addEventListener('click', () => toolpath && toolpath.fit('top'));
byId('view-iso').addEventListener('click', () => toolpath && toolpath.fit('iso'));
byId('view-fit').addEventListener('click', () => toolpath && toolpath.fit());
const errorScale = byId('error-scale');
errorScale.addEventListener('change', () => {
  const scaleMm = Number(errorScale.value);
  setText(byId('scale-labels'), `0 – ${scaleMm.toFixed(3)} mm`);
  if (toolpath) {
    toolpath.setErrorScale(scaleMm);
  }
});

loadState().then(() => live.start());
controls.loadCatalogue();
