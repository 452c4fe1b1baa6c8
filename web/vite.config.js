// Vite 7 build of the visualizer into web/dist, which dance-server serves at `/`.
// `base: './'` keeps every asset URL relative, so the page also works behind a path prefix.
// `npm run dev` proxies the API and WebSockets to a server on DANCE_SERVER (default http://localhost:8080).
import { defineConfig } from 'vite';

const server = process.env.DANCE_SERVER || 'http://localhost:8080';

export default defineConfig({
  base: './',
  build: {
    outDir: 'dist',
    emptyOutDir: true,
    target: 'es2022',
    chunkSizeWarningLimit: 800,
  },
  server: {
    proxy: {
      '/api': server,
      '/metrics': server,
      '/ws': { target: server.replace(/^http/, 'ws'), ws: true },
    },
  },
});
