// Command-line options of the form --name value.

export function parseArgs(argv, known) {
  const options = {};
  for (let i = 0; i < argv.length; i++) {
    const arg = argv[i];
    const name = arg.startsWith('--') ? arg.slice(2) : null;
    if (!name || !known.includes(name)) {
      throw new Error(`unknown argument ${JSON.stringify(arg)}; known: ${known.map((k) => `--${k}`).join(' ')}`);
    }
    if (i + 1 >= argv.length) {
      throw new Error(`--${name} needs a value`);
    }
    options[name] = argv[++i];
  }
  return options;
}
