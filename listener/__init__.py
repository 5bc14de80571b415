"""The listener service: wire codec, sequence buffers, pipeline core, asyncio daemon, OBCU link."""
