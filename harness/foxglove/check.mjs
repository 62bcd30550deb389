// Read MCAP files with Foxglove's readers: McapIndexedReader (seeks by the summary's indexes)
// and McapStreamReader (reads records in order). Prints messages per file; exit 1 on error.
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { open } from "node:fs/promises";
import { readFileSync } from "node:fs";
import zstd from "@foxglove/wasm-zstd";
await zstd.isLoaded;
const decompressHandlers = { zstd: (buf, size) => zstd.decompress(buf, Number(size)) };
let failed = 0;
for (const path of process.argv.slice(2)) {
  try {
    const fh = await open(path, "r");
    const readable = {
      size: async () => BigInt((await fh.stat()).size),
      read: async (offset, length) => {
        const buf = new Uint8Array(Number(length));
        await fh.read(buf, 0, Number(length), Number(offset));
        return buf;
      },
    };
    const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
    let indexed = 0;
    for await (const _ of reader.readMessages()) indexed++;
    await fh.close();
    const stream = new McapStreamReader({ decompressHandlers });
    stream.append(readFileSync(path));
    let streamed = 0, rec;
    while ((rec = stream.nextRecord()) !== undefined) if (rec.type === "Message") streamed++;
    console.log(`${path}: McapIndexedReader ${indexed} messages, McapStreamReader ${streamed}`);
    if (indexed !== streamed) failed = 1;
  } catch (e) {
    console.log(`${path}: ${e.message}`); failed = 1;
  }
}
process.exit(failed);
