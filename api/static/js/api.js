// REST calls to /api/v1, the control token, the authentication banner and the message line.
import { $ } from "./util.js";

export const API = "/api/v1";
const TOKEN_KEY = "thermocomp-token";

// The token: from the address `thermocomp serve` prints (…/?token=…, Jupyter's convention),
// else the one this browser stored. The address bar then drops it: it stays out of the
// history, bookmarks and screen shares (the server never logs it: access_log is off).
export const auth = {
  token: localStorage.getItem(TOKEN_KEY) || "",
  refused: false, // the token was refused for reading: read anonymously meanwhile
  fromAddress: false,
};

export function takeTokenFromAddress() {
  const url = new URL(window.location.href);
  const given = url.searchParams.get("token");
  if (given === null) return;
  url.searchParams.delete("token");
  window.history.replaceState(null, "", url.pathname + url.search + url.hash);
  if (given.trim()) setToken(given.trim());
  auth.fromAddress = true;
}

export function setToken(token) {
  auth.token = token;
  auth.refused = false;
  localStorage.setItem(TOKEN_KEY, token);
}

export function authHeaders(reading = true) {
  return auth.token && !(reading && auth.refused) ? { Authorization: `Bearer ${auth.token}` } : {};
}

export function apiError(response, data) {
  // the API's error body: {"status", "kind", "message", "details"}
  const error = new Error((data && data.message) || `${response.status} ${response.statusText}`);
  error.status = response.status;
  error.kind = data && data.kind;
  error.body = data;
  return error;
}

let onRefusedRead = () => {};
export function whenReadRefused(callback) { onRefusedRead = callback; }

export async function api(method, path, body) {
  // a refused token is still sent with control requests (their answer says it is refused)
  // but not with reads, which the server may allow anonymously: the plots keep going
  const reading = method === "GET";
  const headers = { Accept: "application/json", ...authHeaders(reading) };
  if (body !== undefined) headers["Content-Type"] = "application/json";
  const response = await fetch(API + path, {
    method,
    headers,
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  const text = await response.text();
  let data = null;
  try { data = text ? JSON.parse(text) : null; } catch { data = { message: text }; }
  if (response.status === 401 || response.status === 403) {
    const error = apiError(response, data);
    authFailed(error, reading && Boolean(headers.Authorization));
    throw error;
  }
  if (!response.ok) throw apiError(response, data);
  return data;
}

// --- authentication banner: a refused token never clears or freezes the plots ----------

const WHERE_TOKEN = "open the address `make run` (thermocomp serve) printed — it ends in "
  + "?token=… — or paste the token from the data directory's control-token file above";

function authFailed(error, readWithToken) {
  const banner = $("auth-banner");
  const what = auth.token ? "The token was refused" : "A control token is needed";
  const why = `${error.status} ${error.kind || ""}: ${error.message}`.replace(/ +:/, ":");
  let next;
  if (readWithToken && error.status === 401) {
    // an unknown token: read without it (the server may allow anonymous reading)
    if (!auth.refused) {
      auth.refused = true;
      onRefusedRead();
    }
    next = "Reading on without it where the server allows: the plots keep what they show "
      + `and go on. To control the run, ${WHERE_TOKEN}.`;
  } else if (auth.refused && error.status === 401) {
    next = "Reading needs a valid token here: the plots keep what they show until one is "
      + "entered above.";
  } else if (!auth.token) {
    next = `To control the robot, ${WHERE_TOKEN}; the plots keep what they show.`;
  } else {
    next = "Enter a token with the needed scope above; the plots keep what they show.";
  }
  banner.replaceChildren();
  const strong = document.createElement("strong");
  strong.textContent = `${what} (${why}). `;
  banner.append(strong, document.createTextNode(next));
  banner.hidden = false;
  banner.dataset.status = String(error.status);
}

export function hideBanner() {
  $("auth-banner").hidden = true;
}

export function say(text, isError = false) {
  const message = $("message");
  message.textContent = text;
  message.className = isError ? "error" : "ok";
}

export function fail(error, doing) {
  const prefix = doing ? `${doing}: ` : "";
  const status = error.status ? `${error.status} ` : "";
  const kind = error.kind ? `${error.kind}: ` : "";
  let details = "";
  if (error.body && Array.isArray(error.body.details)) {
    details = error.body.details
      .map((d) => (d && d.field ? `${d.field}: ${d.message}` : JSON.stringify(d)))
      .join("; ");
  }
  const hint = error.status === 401 || error.status === 403 ? " (a control token is needed)" : "";
  say(`${prefix}${status}${kind}${error.message}${details ? ` (${details})` : ""}${hint}`, true);
}
