// The independent OPC UA client of tests/opcua: node-opcua, driven line by line.
//
// stdin: one JSON command a line; stdout: one JSON answer a line ({"id", "ok", ...} or
// {"id", "ok": false, "error"}), plus {"event": "change", ...} lines for monitored items.
// Commands: connect, namespace, browse, read, write, subscribe, monitor, close.
// It shares no code with fieldgate's server (asyncua): a second implementation of the protocol.
"use strict";
const fs = require("fs");
const readline = require("readline");
const {
  OPCUAClient,
  MessageSecurityMode,
  SecurityPolicy,
  AttributeIds,
  ClientSubscription,
  ClientMonitoredItem,
  TimestampsToReturn,
  DataType,
  DataChangeFilter,
  DataChangeTrigger,
  DeadbandType,
  UserTokenType,
  BrowseDirection,
  NodeClass,
} = require("node-opcua-client");
const { OPCUACertificateManager } = require("node-opcua-certificate-manager");

let client = null;
let session = null;
const subscriptions = [];

function out(obj) {
  process.stdout.write(JSON.stringify(obj) + "\n");
}

function status(sc) {
  return { name: sc.name, value: sc.value >>> 0 };
}

function plain(v) {
  if (v === null || v === undefined) return null;
  if (typeof v === "bigint") return Number(v);
  if (v instanceof Date) return v.toISOString();
  if (typeof v === "object" && "text" in v) return v.text; // LocalizedText
  if (typeof v === "object" && v.low !== undefined && v.high !== undefined) return { low: v.low, high: v.high }; // Range
  if (typeof v === "object" && v.unitId !== undefined) return { unitId: v.unitId, displayName: v.displayName && v.displayName.text }; // EUInformation
  return v;
}

function dataValue(dv) {
  return {
    value: dv.value ? plain(dv.value.value) : null,
    dataType: dv.value ? DataType[dv.value.dataType] : null,
    status: status(dv.statusCode),
    sourceTimestamp: dv.sourceTimestamp ? dv.sourceTimestamp.toISOString() : null,
    serverTimestamp: dv.serverTimestamp ? dv.serverTimestamp.toISOString() : null,
  };
}

const handlers = {
  async connect(cmd) {
    const mode = MessageSecurityMode[cmd.securityMode || "None"];
    const policy = cmd.securityMode && cmd.securityMode !== "None" ? SecurityPolicy.Basic256Sha256 : SecurityPolicy.None;
    const options = {
      applicationName: "fieldgate-test-client",
      applicationUri: cmd.applicationUri || "urn:fieldgate:test-client",
      securityMode: mode,
      securityPolicy: policy,
      endpointMustExist: false,
      connectionStrategy: { maxRetry: 0, initialDelay: 100, maxDelay: 200 },
      requestedSessionTimeout: 60000,
    };
    if (cmd.pkiDir) {
      const manager = new OPCUACertificateManager({ rootFolder: cmd.pkiDir, automaticallyAcceptUnknownCertificate: true });
      await manager.initialize();
      options.clientCertificateManager = manager;
    }
    if (cmd.certFile) {
      options.certificateFile = cmd.certFile;
      options.privateKeyFile = cmd.keyFile;
    }
    client = OPCUAClient.create(options);
    await client.connect(cmd.url);
    const identity = cmd.user
      ? { type: UserTokenType.UserName, userName: cmd.user, password: cmd.password }
      : { type: UserTokenType.Anonymous };
    session = await client.createSession(identity);
    return {};
  },

  async namespace(cmd) {
    const dv = await session.read({ nodeId: "ns=0;i=2255", attributeId: AttributeIds.Value });
    return { index: dv.value.value.indexOf(cmd.uri), array: dv.value.value };
  },

  async browse(cmd) {
    // every node below cmd.nodeId (recursively, hierarchical references), with its class
    const found = [];
    const queue = [cmd.nodeId || "ns=0;i=85"];
    while (queue.length) {
      const nodeId = queue.shift();
      const result = await session.browse({
        nodeId,
        browseDirection: BrowseDirection.Forward,
        referenceTypeId: "HierarchicalReferences",
        includeSubtypes: true,
        resultMask: 0x3f,
      });
      for (const ref of result.references || []) {
        const id = ref.nodeId.toString();
        if (ref.nodeId.namespace === 0) continue; // the standard nodes (Server object, ...)
        found.push({ nodeId: id, browseName: ref.browseName.name, nodeClass: NodeClass[ref.nodeClass], parent: nodeId });
        if (ref.nodeClass === NodeClass.Object) queue.push(id);
        if (ref.nodeClass === NodeClass.Variable && cmd.properties) queue.push(id);
      }
    }
    return { nodes: found };
  },

  async read(cmd) {
    const attributeId = AttributeIds[cmd.attribute || "Value"];
    const dvs = await session.read(cmd.nodeIds.map((nodeId) => ({ nodeId, attributeId })), TimestampsToReturn.Both);
    return { values: dvs.map(dataValue) };
  },

  async write(cmd) {
    const statuses = await session.write({
      nodeId: cmd.nodeId,
      attributeId: AttributeIds.Value,
      value: { value: { dataType: DataType[cmd.dataType], value: cmd.value } },
    });
    return { status: status(statuses) };
  },

  async subscribe(cmd) {
    const sub = ClientSubscription.create(session, {
      requestedPublishingInterval: cmd.publishingInterval || 100,
      requestedLifetimeCount: 600,
      requestedMaxKeepAliveCount: 20,
      maxNotificationsPerPublish: 0,
      publishingEnabled: true,
      priority: 1,
    });
    await new Promise((resolve, reject) => {
      sub.on("started", resolve);
      sub.on("internal_error", reject);
    });
    subscriptions.push(sub);
    return { subscription: subscriptions.length - 1, publishingInterval: sub.publishingInterval };
  },

  async monitor(cmd) {
    const sub = subscriptions[cmd.subscription || 0];
    const results = [];
    for (const nodeId of cmd.nodeIds) {
      const parameters = { samplingInterval: cmd.samplingInterval ?? 100, discardOldest: true, queueSize: cmd.queueSize || 10 };
      if (cmd.deadband) {
        parameters.filter = new DataChangeFilter({
          trigger: DataChangeTrigger.StatusValue,
          deadbandType: DeadbandType[cmd.deadband.type],
          deadbandValue: cmd.deadband.value,
        });
      }
      try {
        const item = await sub.monitor({ nodeId, attributeId: AttributeIds.Value }, parameters, TimestampsToReturn.Both);
        if (item.statusCode && item.statusCode.isNotGood()) {
          results.push({ nodeId, ok: false, error: item.statusCode.name });
          continue;
        }
        item.on("changed", (dv) => out({ event: "change", nodeId, t: Date.now(), ...dataValue(dv) }));
        item.on("err", (message) => out({ event: "error", nodeId, message: String(message) }));
        results.push({ nodeId, ok: true });
      } catch (err) {
        results.push({ nodeId, ok: false, error: String(err.message || err) });
      }
    }
    return { items: results };
  },

  async close() {
    for (const sub of subscriptions) await sub.terminate().catch(() => {});
    if (session) await session.close().catch(() => {});
    if (client) await client.disconnect().catch(() => {});
    return {};
  },
};

const rl = readline.createInterface({ input: process.stdin });
let chain = Promise.resolve();
rl.on("line", (line) => {
  if (!line.trim()) return;
  const cmd = JSON.parse(line);
  chain = chain.then(async () => {
    try {
      const result = await handlers[cmd.cmd](cmd);
      out({ id: cmd.id, ok: true, ...result });
    } catch (err) {
      out({ id: cmd.id, ok: false, error: String((err && err.message) || err) });
    }
    if (cmd.cmd === "close") process.exit(0);
  });
});
rl.on("close", () => chain.then(() => process.exit(0)));
