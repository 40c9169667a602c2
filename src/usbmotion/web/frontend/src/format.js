// How numbers are shown, and small DOM helpers shared by the panels.

// Millimetres with 3 decimals; -0.000 shows as 0.000 so a figure at rest does not flicker.
export function mm(value) {
  if (typeof value !== 'number' || !Number.isFinite(value)) {
    return '—';
  }
  const text = value.toFixed(3);
  return text === '-0.000' ? '0.000' : text;
}

// Seconds as m:ss (h:mm:ss past an hour).
export function duration(seconds) {
  if (typeof seconds !== 'number' || !Number.isFinite(seconds) || seconds < 0) {
    return '—';
  }
  const whole = Math.round(seconds);
  const hours = Math.floor(whole / 3600);
  const minutes = Math.floor((whole % 3600) / 60);
  const rest = String(whole % 60).padStart(2, '0');
  return hours > 0 ? `${hours}:${String(minutes).padStart(2, '0')}:${rest}` : `${minutes}:${rest}`;
}

// An element with attributes and children: el('td', {class: 'x'}, 'text').
export function el(tag, attributes = {}, ...children) {
  const element = document.createElement(tag);
  for (const [name, value] of Object.entries(attributes)) {
    if (value === false || value === null || value === undefined) {
      continue;
    }
    if (name === 'class') {
      element.className = value;
    } else if (name === 'text') {
      element.textContent = value;
    } else {
      element.setAttribute(name, value === true ? '' : value);
    }
  }
  element.append(...children);
  return element;
}

// Sets an element's text only when it changed: the state comes 50 times a second and most
// figures stay the same.
export function setText(element, text) {
  if (element.textContent !== text) {
    element.textContent = text;
  }
}

export function byId(id) {
  const element = document.getElementById(id);
  if (!element) {
    throw new Error(`the page has no element #${id}`);
  }
  return element;
}
