// Reads a cellguard record with the official TypeScript readers, as Foxglove does, and prints one
// JSON document of what it found: usage `node read_record.mjs RECORD.mcap`.
// @mcap/core reads the file (indexed, CRCs checked), @foxglove/rosmsg parses the ros2msg schemas
// and @foxglove/rosmsg2-serialization decodes the CDR messages.
import { open } from "node:fs/promises";

import { McapIndexedReader } from "@mcap/core";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import zstd from "@foxglove/wasm-zstd";

const path = process.argv[2];
await zstd.isLoaded;
const handle = await open(path, "r");
const readable = {
  size: async () => BigInt((await handle.stat()).size),
  read: async (offset, length) => {
    const buffer = new Uint8Array(Number(length));
    await handle.read(buffer, 0, Number(length), Number(offset));
    return buffer;
  },
};
const reader = await McapIndexedReader.Initialize({
  readable,
  decompressHandlers: { zstd: (data, size) => zstd.decompress(data, Number(size)) },
});

const decoders = new Map();
function decoder(channelId) {
  if (!decoders.has(channelId)) {
    const channel = reader.channelsById.get(channelId);
    const schema = reader.schemasById.get(channel.schemaId);
    let decode;
    if (schema.encoding === "jsonschema") {
      out.jsonSchemas[channel.topic] = JSON.parse(new TextDecoder().decode(schema.data));
    }
    if (channel.messageEncoding === "cdr") {
      const messageReader = new MessageReader(parse(new TextDecoder().decode(schema.data), { ros2: true }));
      decode = (data) => messageReader.readMessage(data);
    } else {
      decode = (data) => JSON.parse(new TextDecoder().decode(data));
    }
    decoders.set(channelId, { topic: channel.topic, schema: schema.name, decode });
  }
  return decoders.get(channelId);
}

const out = { messages: 0, topics: {}, firstLogTime: null, ordered: true, jointStates: [], logs: [], tf: null,
              metadata: {}, attachments: [], jsonSchemas: {}, events: [] };
let last = -1n;
for await (const message of reader.readMessages({ validateCrcs: true })) {
  const { topic, schema, decode } = decoder(message.channelId);
  const value = decode(message.data);
  out.messages += 1;
  out.topics[topic] = { schema, count: (out.topics[topic]?.count ?? 0) + 1 };
  if (out.firstLogTime === null) out.firstLogTime = message.logTime.toString();
  if (message.logTime < last) out.ordered = false;
  last = message.logTime;
  if (topic === "/joint_states" && out.jointStates.length < 3) {
    out.jointStates.push({ name: value.name, position: Array.from(value.position), stamp: value.header.stamp,
                           logTime: message.logTime.toString() });
  } else if (topic === "/events/log" && out.logs.length < 50) {
    out.logs.push({ level: value.level, name: value.name, msg: value.msg, stamp: value.stamp });
  } else if (topic === "/events" && out.events.length < 50) {
    out.events.push(value);
  } else if (topic === "/tf" && out.tf === null) {
    out.tf = value.transforms.map((t) => ({ parent: t.header.frame_id, child: t.child_frame_id }));
  }
}
for await (const record of reader.readMetadata()) out.metadata[record.name] = Object.fromEntries(record.metadata);
for await (const record of reader.readAttachments()) {
  out.attachments.push({ name: record.name, mediaType: record.mediaType,
                         head: new TextDecoder().decode(record.data.slice(0, 200)) });
}
await handle.close();
process.stdout.write(JSON.stringify(out) + "\n");
