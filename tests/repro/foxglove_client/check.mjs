// What the Foxglove app (and Lichtblick) would get from a live view, checked with the
// protocol's own JavaScript client.
//
//   node check.mjs ws://127.0.0.1:8765 [--seconds S] [--connect-s S] [--json OUT] [--table]
//
// It connects the way the app's WebSocket player does (npm @foxglove/ws-protocol's
// FoxgloveClient over a WebSocket offering the app's subprotocols), subscribes to every
// channel as soon as it is advertised (as a layout with a panel on every topic does), and
// for every channel and message does what the app does before a panel sees the data:
//
// * parses the channel's schema by its message and schema encoding.  For JSON with a
//   JSON schema the app turns the schema into its datatypes and refuses the channel
//   ("Failed to parse channel schema") when a property's "type" is anything but one of
//   boolean, string, number, integer, object, array (a list of types, "null" and a
//   property without a type are refused), when a "oneOf" has alternatives other than
//   numeric constants, or an array's items are not one such type; strings with
//   contentEncoding base64 become bytes.  The rules are re-stated here (the app's parser
//   is not published on npm); other encodings are reported as not checked.
// * decodes each message (UTF-8 JSON, base64 fields to bytes), validates it against the
//   advertised schema (ajv) and, for a Foxglove well-known schema name (foxglove.*),
//   against Foxglove's own published JSON schema of that name (npm @foxglove/schemas);
// * compares the message's `timestamp` (foxglove.*) with its log time and with the
//   server's clock: with the `time` capability the app stamps every message with the
//   last time the server sent (before the first one, with zero) and treats a time
//   earlier than the previous one as a seek (it drops the messages not yet shown);
// * exercises every capability the server advertises (parameters, services,
//   connectionGraph, assets, clientPublish) and reports what does not answer.
//
// It collects until the server closes the connection (the run or replay ended) or
// --seconds passed, prints a JSON report (stdout, or --json OUT; --table: a line per
// channel and the failures) and exits 0 when nothing failed, 1 when something did, 2
// when it could not connect.  "lag" is how far a message's log time is behind the
// server's clock when it arrives: the app stamps it with that clock.

import { readFileSync, writeFileSync } from "node:fs";

import foxgloveSchemas from "@foxglove/schemas/jsonschema.js";
import wsProtocol from "@foxglove/ws-protocol";
import AjvModule from "ajv";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;
const Ajv = AjvModule.default ?? AjvModule;

// The subprotocols the app offers, in its order (Lichtblick's FoxgloveWebSocketPlayer).
const APP_SUBPROTOCOLS = [FoxgloveClient.SUPPORTED_SUBPROTOCOL, "foxglove.sdk.v1"];
const KNOWN_CAPABILITIES = [
  "clientPublish",
  "parameters",
  "parametersSubscribe",
  "time",
  "services",
  "connectionGraph",
  "assets",
];
// A capability that does not answer within this long is reported as not implemented.
const ANSWER_S = 3;

function parseArgs(argv) {
  const args = { url: undefined, seconds: 3600, connectS: 30, json: undefined, table: false };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    if (a === "--seconds") args.seconds = Number(argv[++i]);
    else if (a === "--connect-s") args.connectS = Number(argv[++i]);
    else if (a === "--json") args.json = argv[++i];
    else if (a === "--table") args.table = true;
    else if (a === "-h" || a === "--help") {
      process.stdout.write(readFileSync(new URL(import.meta.url), "utf8").split("\n\n")[0]);
      process.exit(0);
    } else if (args.url === undefined) args.url = a;
    else throw new Error(`unexpected argument ${a}`);
  }
  if (!args.url) throw new Error("usage: node check.mjs ws://HOST:PORT [--seconds S] [--json OUT]");
  return args;
}

// ------------------------------------------------------------------ the app's schema rules

class SchemaRefused extends Error {}

const SCALAR_TYPES = new Set(["boolean", "string", "number", "integer"]);

/** Walk a JSON schema as the app's JSON-schema parser does; returns a postprocessing
 * function (base64 strings to bytes) or throws SchemaRefused naming the field. */
function appJsonSchemaPlan(schema, path) {
  if (schema === null || typeof schema !== "object" || schema.type !== "object") {
    throw new SchemaRefused(
      `${path.join(".") || "<root>"}: expected "type": "object", got ${JSON.stringify(schema?.type)}`,
    );
  }
  const steps = [];
  for (const [name, field] of Object.entries(schema.properties ?? {})) {
    const where = path.concat(name).join(".");
    if (Array.isArray(field.oneOf)) {
      if (!field.oneOf.every((alt) => typeof alt.const === "number")) {
        throw new SchemaRefused(`${where}: oneOf alternatives must be numeric constants`);
      }
      continue;
    }
    const t = field.type;
    if (t === "string") {
      if (field.contentEncoding === "base64") steps.push({ name, kind: "base64" });
      else if (field.contentEncoding !== undefined) {
        throw new SchemaRefused(`${where}: contentEncoding ${JSON.stringify(field.contentEncoding)}`);
      }
    } else if (t === "object") {
      steps.push({ name, kind: "object", plan: appJsonSchemaPlan(field, path.concat(name)) });
    } else if (t === "array") {
      const items = field.items ?? {};
      if (items.type === "object") {
        steps.push({ name, kind: "array", plan: appJsonSchemaPlan(items, path.concat(name)) });
      } else if (!SCALAR_TYPES.has(items.type)) {
        throw new SchemaRefused(`${where}: array items of type ${JSON.stringify(items.type)}`);
      } else if (items.type === "string" && items.contentEncoding !== undefined) {
        throw new SchemaRefused(`${where}: contentEncoding on array items`);
      }
    } else if (!SCALAR_TYPES.has(t)) {
      throw new SchemaRefused(`${where}: type ${JSON.stringify(t)} (the app takes one of boolean, string, number, integer, object, array)`);
    }
  }
  return (value) => {
    for (const step of steps) {
      const v = value[step.name];
      if (step.kind === "base64" && typeof v === "string") value[step.name] = Buffer.from(v, "base64");
      else if (step.kind === "object" && v !== null && typeof v === "object") step.plan(v);
      else if (step.kind === "array" && Array.isArray(v)) v.forEach((item) => step.plan(item));
    }
    return value;
  };
}

/** The app's reading of one advertised channel: {decode} or throws (the app's alert). */
function appChannel(channel) {
  const enc = channel.encoding;
  const schemaEncoding = channel.schemaEncoding;
  if (enc === "json" && (schemaEncoding === undefined || schemaEncoding === "jsonschema")) {
    const text = channel.schema ?? "";
    const schema = text.length > 0 ? JSON.parse(text) : undefined;
    if (schema !== undefined && typeof schema !== "object") {
      throw new SchemaRefused(`schema is not a JSON object`);
    }
    const post = schema === undefined ? (v) => v : appJsonSchemaPlan(schema, []);
    const decoder = new TextDecoder("utf-8", { fatal: true });
    return { schema, decode: (bytes) => post(JSON.parse(decoder.decode(bytes))), checked: true };
  }
  const known = {
    protobuf: "protobuf",
    flatbuffer: "flatbuffer",
    ros1: "ros1msg",
    cdr: "ros2msg",
  };
  if (enc in known) {
    // a supported pair, but this check does not decode it (our stack sends JSON only)
    return { schema: undefined, decode: undefined, checked: false };
  }
  throw new SchemaRefused(
    schemaEncoding
      ? `unsupported combination of message / schema encoding: (${enc} / ${schemaEncoding})`
      : `unsupported message encoding ${enc}`,
  );
}

// ------------------------------------------------------------------------- report

function newChannelReport(channel) {
  return {
    id: channel.id,
    encoding: channel.encoding,
    schemaName: channel.schemaName,
    schemaEncoding: channel.schemaEncoding ?? null,
    schemaRefused: null,
    decodeChecked: true,
    wellKnown: null, // "matched" | "missing" (a foxglove.* name @foxglove/schemas lacks) | null
    messages: 0,
    decodeFailures: 0,
    schemaViolations: 0,
    wellKnownViolations: 0,
    firstFailure: null,
    timestampField: null, // messages with a `timestamp` {sec, nsec}
    maxTimestampMinusLogTimeMs: null,
    maxLogTimeMinusClockMs: null,
    logTimeMinusClockMs: null, // {p50, p99, max}: how far behind the app's clock a message came
    beforeFirstTime: 0,
  };
}

function absMax(a, b) {
  if (a === null) return b;
  return Math.abs(b) > Math.abs(a) ? b : a;
}

function main() {
  const args = parseArgs(process.argv.slice(2));
  const report = {
    url: args.url,
    connected: false,
    connectedAtMs: null, // wall clock (ms since the epoch) when the connection opened
    subprotocolOffered: APP_SUBPROTOCOLS,
    subprotocol: null,
    serverInfo: null,
    capabilities: {},
    statusMessages: [],
    connectError: null,
    clientErrors: [],
    duplicateTopics: [],
    unknownSubscription: 0,
    subscribeRaces: [],
    time: { messages: 0, backwards: 0, first: null, last: null },
    channels: {},
    totals: {},
    failures: [],
  };
  const ajv = new Ajv({ strict: false, allErrors: false, validateFormats: false });
  const wellKnownValidators = new Map();
  for (const schema of Object.values(foxgloveSchemas)) {
    if (schema && typeof schema.title === "string") {
      wellKnownValidators.set(schema.title, ajv.compile(schema));
    }
  }
  const bySubscription = new Map();
  const states = [];
  const byTopic = new Map();
  let clockNs = null;
  const pendingAnswers = new Map();
  const startedAt = Date.now();
  let finished = false;

  let ws;
  let client;

  const finish = (why) => {
    if (finished) return;
    finished = true;
    clearTimeout(deadline);
    for (const [cap, state] of pendingAnswers) {
      report.capabilities[cap] = state.answered ? "answered" : `no answer (${state.asked})`;
    }
    report.end = why;
    for (const st of states) st.rep.logTimeMinusClockMs = percentiles(st.lags);
    summarize(report);
    const text = JSON.stringify(report, null, 2) + "\n";
    if (args.json) writeFileSync(args.json, text);
    else if (!args.table) process.stdout.write(text);
    if (args.table) process.stdout.write(table(report));
    try {
      client?.close();
    } catch {
      // already closed
    }
    process.exitCode = report.connected ? (report.failures.length ? 1 : 0) : 2;
    setTimeout(() => process.exit(process.exitCode), 50).unref();
  };
  const deadline = setTimeout(() => finish(`--seconds ${args.seconds} passed`), args.seconds * 1000);
  const connectTimer = setTimeout(() => {
    if (!report.connected) finish(`not connected within ${args.connectS} s`);
  }, args.connectS * 1000);

  const ask = (cap, what, fn) => {
    pendingAnswers.set(cap, { asked: what, answered: false });
    fn();
    setTimeout(() => {
      const st = pendingAnswers.get(cap);
      if (st && !st.answered) report.failures.push(`capability ${cap}: no answer to ${what} within ${ANSWER_S} s`);
    }, ANSWER_S * 1000).unref();
  };
  const answered = (cap) => {
    const st = pendingAnswers.get(cap);
    if (st) st.answered = true;
  };

  const connect = () => {
    if (finished) return;
    ws = new WebSocket(args.url, APP_SUBPROTOCOLS);
    client = new FoxgloveClient({ ws });
    client.on("open", () => {
      report.connected = true;
      report.connectedAtMs = Date.now();
      clearTimeout(connectTimer);
      report.subprotocol = ws.protocol || null;
    });
    client.on("error", (err) => {
      const text = String(err?.message ?? err);
      if (report.connected) report.clientErrors.push(text);
      else report.connectError = text; // retried until --connect-s, as the app retries
    });
    client.on("close", () => {
      if (report.connected) finish("the server closed the connection");
      else if (Date.now() - startedAt < args.connectS * 1000) setTimeout(connect, 100);
    });
    client.on("serverInfo", (info) => {
      report.serverInfo = info;
      const caps = Array.isArray(info.capabilities) ? info.capabilities : null;
      if (caps === null) {
        report.failures.push(`serverInfo.capabilities is not a list: ${JSON.stringify(info.capabilities)}`);
        return;
      }
      for (const cap of caps) {
        report.capabilities[cap] = KNOWN_CAPABILITIES.includes(cap) ? "advertised" : "unknown to the app";
        if (!KNOWN_CAPABILITIES.includes(cap)) report.failures.push(`capability ${cap}: unknown to the app`);
      }
      if (caps.includes("parameters")) ask("parameters", "getParameters([])", () => client.getParameters([], "check"));
      if (caps.includes("connectionGraph")) ask("connectionGraph", "subscribeConnectionGraph", () => client.subscribeConnectionGraph());
      if (caps.includes("assets")) ask("assets", "fetchAsset", () => client.fetchAsset("package://none", 1));
      if (caps.includes("services")) ask("services", "an advertiseServices message", () => {});
      if (caps.includes("clientPublish")) {
        const encodings = info.supportedEncodings ?? [];
        if (!encodings.some((e) => ["json", "ros1", "cdr"].includes(e))) {
          report.failures.push(`capability clientPublish: supportedEncodings ${JSON.stringify(encodings)} has none the app publishes in`);
        }
      }
    });
    client.on("status", (s) => {
      const entry = { level: s.level, message: s.message };
      report.statusMessages.push(entry);
      // foxglove-sdk (0.30.3, and its main branch as of 2026-12) sends a channel's
      // advertisement before it registers the channel for the client
      // (rust/foxglove/src/websocket/connected_client.rs, advertise_channels): a client that
      // subscribes at once can be told the channel is unknown.  A channel that was advertised
      // and never unadvertised is subscribed again, once (the view holds a new channel's
      // messages for 0.5 s, so the retry still gets them all); the race is reported, not failed.
      const m = /^Unknown channel ID: (\d+)$/.exec(String(s.message));
      if (!m) return;
      const id = Number(m[1]);
      const state = states.find((st) => st.channel.id === id && byTopic.get(st.channel.topic) === st);
      if (!state || state.retried) return;
      state.retried = true;
      entry.subscribeRaceRetried = true;
      report.subscribeRaces.push({ channel: id, topic: state.channel.topic });
      bySubscription.set(client.subscribe(id), state);
    });
    client.on("parameterValues", () => answered("parameters"));
    client.on("connectionGraphUpdate", () => answered("connectionGraph"));
    client.on("fetchAssetResponse", () => answered("assets"));
    client.on("advertiseServices", () => answered("services"));
    client.on("time", ({ timestamp }) => {
      const t = BigInt(timestamp);
      const tm = report.time;
      tm.messages++;
      if (clockNs !== null && t < clockNs) tm.backwards++;
      if (tm.first === null) tm.first = t.toString();
      tm.last = t.toString();
      clockNs = t;
    });
    client.on("advertise", (channels) => {
      for (const ch of channels) {
        const existing = byTopic.get(ch.topic);
        if (existing && existing.channel.id !== ch.id) {
          report.duplicateTopics.push(`${ch.topic} (${existing.channel.id} and ${ch.id})`);
          continue;
        }
        const rep = newChannelReport(ch);
        report.channels[ch.topic] = rep;
        let parsed;
        try {
          parsed = appChannel(ch);
        } catch (err) {
          rep.schemaRefused = String(err.message ?? err);
          parsed = { schema: safeJson(ch.schema), decode: undefined, checked: false };
        }
        rep.decodeChecked = parsed.checked;
        let validate;
        if (parsed.schema !== undefined && ch.encoding === "json") {
          try {
            validate = ajv.compile(parsed.schema);
          } catch (err) {
            rep.schemaRefused ??= `ajv cannot compile the schema: ${err.message}`;
          }
        }
        let wellKnown;
        if (typeof ch.schemaName === "string" && ch.schemaName.startsWith("foxglove.")) {
          wellKnown = wellKnownValidators.get(ch.schemaName);
          rep.wellKnown = wellKnown ? "matched" : "missing";
        }
        const state = { channel: ch, rep, parsed, validate, wellKnown, lags: [] };
        byTopic.set(ch.topic, state);
        // the app subscribes as soon as a channel a panel wants is advertised
        bySubscription.set(client.subscribe(ch.id), state);
        states.push(state);
      }
    });
    client.on("unadvertise", (ids) => {
      for (const [topic, st] of byTopic) if (ids.includes(st.channel.id)) byTopic.delete(topic);
    });
    client.on("message", ({ subscriptionId, timestamp, data }) => {
      const st = bySubscription.get(subscriptionId);
      if (!st) {
        report.unknownSubscription++;
        return;
      }
      const rep = st.rep;
      rep.messages++;
      const logNs = BigInt(timestamp);
      if (clockNs === null) rep.beforeFirstTime++;
      else {
      const lag = Number(logNs - clockNs) / 1e6;
      rep.maxLogTimeMinusClockMs = absMax(rep.maxLogTimeMinusClockMs, lag);
      st.lags.push(lag);
    }
      const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
      if (st.channel.encoding !== "json") return;
      let raw;
      try {
        raw = JSON.parse(new TextDecoder("utf-8", { fatal: true }).decode(bytes));
        if (st.parsed.decode) st.parsed.decode(bytes);
      } catch (err) {
        rep.decodeFailures++;
        rep.firstFailure ??= `decode: ${err.message}`;
        return;
      }
      if (st.validate && !st.validate(raw)) {
        rep.schemaViolations++;
        rep.firstFailure ??= `schema: ${ajv.errorsText(st.validate.errors)} in ${clip(bytes)}`;
      }
      if (st.wellKnown && !st.wellKnown(raw)) {
        rep.wellKnownViolations++;
        rep.firstFailure ??= `${st.channel.schemaName}: ${ajv.errorsText(st.wellKnown.errors)}`;
      }
      const ts = raw?.timestamp;
      if (ts && typeof ts === "object" && Number.isInteger(ts.sec) && Number.isInteger(ts.nsec)) {
        rep.timestampField = (rep.timestampField ?? 0) + 1;
        const tsNs = BigInt(ts.sec) * 1000000000n + BigInt(ts.nsec);
        rep.maxTimestampMinusLogTimeMs = absMax(rep.maxTimestampMinusLogTimeMs, Number(tsNs - logNs) / 1e6);
      }
    });
  };
  connect();
  report.startedAtMs = startedAt;
}

function percentiles(values) {
  if (values.length === 0) return null;
  const v = [...values].sort((a, b) => a - b);
  const at = (q) => v[Math.min(v.length - 1, Math.floor(q * v.length))];
  return { p50: at(0.5), p1: at(0.01), min: v[0], max: v[v.length - 1] };
}

/** One line per channel and the verdict: what --table prints. */
function table(report) {
  const rows = [["topic", "schema", "messages", "refused", "decode", "invalid", "foxglove", "lag p50/max ms"]];
  for (const [topic, c] of Object.entries(report.channels).sort()) {
    const lag = c.logTimeMinusClockMs;
    rows.push([
      topic,
      c.schemaName,
      String(c.messages),
      c.schemaRefused ? "REFUSED" : "-",
      String(c.decodeFailures),
      String(c.schemaViolations),
      c.wellKnown ? (c.wellKnownViolations ? `${c.wellKnownViolations} bad` : c.wellKnown) : "-",
      lag ? `${(-lag.p50).toFixed(0)}/${(-lag.min).toFixed(0)}` : "-",
    ]);
  }
  const widths = rows[0].map((_, i) => Math.max(...rows.map((r) => r[i].length)));
  const lines = rows.map((r) => r.map((v, i) => (i < 2 ? v.padEnd(widths[i]) : v.padStart(widths[i]))).join("  "));
  const t = report.totals;
  lines.push(
    `${t.channels} channels, ${t.messages} messages; subprotocol ${report.subprotocol}; ` +
      `capabilities ${Object.keys(report.capabilities).join(", ") || "none"}; ` +
      `time messages ${report.time.messages}, backwards ${report.time.backwards}`,
  );
  lines.push(report.failures.length ? `FAILURES (${report.failures.length}):` : "no failures");
  for (const f of report.failures) lines.push(`  ${f}`);
  return lines.join("\n") + "\n";
}

function safeJson(text) {
  try {
    return JSON.parse(text);
  } catch {
    return undefined;
  }
}

function clip(bytes) {
  const s = Buffer.from(bytes).toString("utf8");
  return s.length > 200 ? `${s.slice(0, 200)}...` : s;
}

function summarize(report) {
  const chans = Object.entries(report.channels);
  const totals = {
    channels: chans.length,
    messages: 0,
    decodeFailures: 0,
    schemaViolations: 0,
    wellKnownViolations: 0,
    schemaRefused: 0,
    silent: 0,
  };
  for (const [topic, c] of chans) {
    totals.messages += c.messages;
    totals.decodeFailures += c.decodeFailures;
    totals.schemaViolations += c.schemaViolations;
    totals.wellKnownViolations += c.wellKnownViolations;
    if (c.messages === 0) totals.silent++;
    if (c.schemaRefused) {
      totals.schemaRefused++;
      report.failures.push(`${topic}: the app refuses the schema: ${c.schemaRefused}`);
    }
    if (c.wellKnown === "missing") report.failures.push(`${topic}: ${c.schemaName} is not a Foxglove schema`);
    for (const k of ["decodeFailures", "schemaViolations", "wellKnownViolations"]) {
      if (c[k]) report.failures.push(`${topic}: ${c[k]} ${k} (${c.firstFailure})`);
    }
  }
  report.totals = totals;
  if (!report.subprotocol) report.failures.push("no subprotocol negotiated");
  else if (!APP_SUBPROTOCOLS.includes(report.subprotocol)) report.failures.push(`subprotocol ${report.subprotocol} is not one the app offers`);
  if (report.capabilities.time && report.time.messages === 0) report.failures.push("capability time: no time message received");
  if (report.time.backwards) report.failures.push(`the server's time went backwards ${report.time.backwards} times (the app seeks and drops what it had not shown)`);
  if (report.duplicateTopics.length) report.failures.push(`topics advertised twice: ${report.duplicateTopics.join(", ")}`);
  if (report.unknownSubscription) report.failures.push(`${report.unknownSubscription} messages on subscriptions never made`);
  if (report.clientErrors.length) report.failures.push(`${report.clientErrors.length} client errors, e.g. ${report.clientErrors[0]}`);
  for (const s of report.statusMessages) {
    if (s.level >= 1 && !s.subscribeRaceRetried) report.failures.push(`server status (level ${s.level}): ${s.message}`);
  }
}

main();
