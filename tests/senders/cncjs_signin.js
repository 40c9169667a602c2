// The token cncjs's Socket.IO API asks for: an empty sign-in to a server with no users gets
// one (the scripts that drive cncjs in the sender tests share it).
'use strict';

const http = require('http');

function signin(url) {
  return new Promise((resolve, reject) => {
    const request = http.request(`${url}/api/signin`, {
      method: 'POST', headers: { 'Content-Type': 'application/json' },
    }, (response) => {
      let body = '';
      response.on('data', (chunk) => { body += chunk; });
      response.on('end', () => {
        try { resolve(JSON.parse(body).token); } catch (error) { reject(error); }
      });
    });
    request.on('error', reject);
    request.end('{}');
  });
}

module.exports = { signin };
