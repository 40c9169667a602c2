"""The host: transport, device client, streaming, machine, configuration, discovery."""
