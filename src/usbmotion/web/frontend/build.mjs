// Builds the page's bundle: src/main.js into ../static/dist/app.js, uPlot's CSS into
// ../static/dist/app.css. Run from anywhere: node build.mjs
import { build } from 'esbuild';
import { fileURLToPath } from 'node:url';
import path from 'node:path';

const here = path.dirname(fileURLToPath(import.meta.url));
const dist = path.join(here, '..', 'static', 'dist');

await build({
  absWorkingDir: here,
  entryPoints: { app: 'src/main.js' },
  bundle: true,
  format: 'esm',
  target: ['es2022'],
  minify: true,
  sourcemap: true,
  outdir: dist,
  logLevel: 'info',
});

await build({
  absWorkingDir: here,
  entryPoints: { app: 'node_modules/uplot/dist/uPlot.min.css' },
  bundle: true,
  minify: true,
  outdir: dist,
  logLevel: 'info',
});
